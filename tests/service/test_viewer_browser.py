"""The viewer (GET /) in a real headless Chromium against a real server: it shows what ``render``
answers for its camera, orbits, pans and zooms with the mouse, lists the scenes, and shows a new
version of its scene without being asked."""

from __future__ import annotations

import io
import json

import browser
import httpx
import numpy as np
import pytest
from PIL import Image
from sensor_helpers import MESHES, put_room
from server_process import ServerProcess

from service.client import Client

pytestmark = pytest.mark.skipif(browser.missing() is not None, reason=str(browser.missing()))


def _rebuilt() -> tuple[type[Exception], ...]:
    """What a poll may meet while the page rebuilds its list of scenes: an element it found is
    replaced before it is read (a stale reference), so the poll looks again."""
    try:
        from selenium.common.exceptions import StaleElementReferenceException
    except ImportError:  # the tests that poll are skipped without selenium
        return ()
    return (StaleElementReferenceException,)


REBUILT = _rebuilt()


@pytest.fixture(scope="module")
def url():
    server = ServerProcess({})
    try:
        yield server.wait_ready()
    finally:
        server.stop()


@pytest.fixture(scope="module")
def driver():
    with browser.chromium() as driver:
        yield driver


@pytest.fixture
def room(url, scene_name):
    with Client(url) as api:
        put_room(api, scene_name)
    return scene_name


def pixels(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def shown(driver) -> tuple[dict, bytes, str]:
    """(the camera of the shown picture, its PNG, the scene version it shows)."""
    picture = driver.find_element("id", "view")
    camera = json.loads(picture.get_attribute("data-camera"))
    return camera, browser.shown_png(driver), picture.get_attribute("data-version")


def assert_is_the_render_of_its_camera(url, scene, camera, png) -> None:
    """The page shows exactly what POST render answers for the same camera."""
    response = httpx.post(f"{url}/v1/scenes/{scene}/render", json=camera, timeout=60)
    assert response.status_code == 200, response.text
    assert np.array_equal(pixels(response.content), pixels(png))


def open_viewer(driver, url, scene) -> int:
    """Load the viewer afresh on ``scene`` and wait for its first picture."""
    driver.get("about:blank")
    driver.get(f"{url}/#scene={scene}&up=z")
    return browser.wait_for_picture(driver)


def distance(camera) -> float:
    return float(np.linalg.norm(np.subtract(camera["eye"], camera["target"])))


def test_the_page_shows_the_render_of_its_camera_and_links_to_the_docs(driver, url, room):
    driver.get_log("browser")  # what earlier pages logged
    open_viewer(driver, url, room)
    errors = [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    assert errors == []  # not even a missing /favicon.ico
    camera, png, version = shown(driver)
    assert camera["width"] == 640 and camera["height"] == 480 and camera["up"] == [0, 0, 1]
    assert version == "3"
    assert_is_the_render_of_its_camera(url, room, camera, png)
    # what the browser paints is that picture (a screenshot of the element, colour-managed)
    painted = pixels(driver.find_element("id", "view").screenshot_as_png)
    assert painted.shape == (480, 640, 3)
    assert np.abs(painted - pixels(png)).mean() < 1.0
    links = {a.get_attribute("pathname") for a in driver.find_elements("css selector", "nav a")}
    assert {"/docs", "/openapi.json", "/health", "/metrics"} <= links


def test_dragging_orbits_around_the_target(driver, url, room):
    count = open_viewer(driver, url, room)
    before, first, _ = shown(driver)
    browser.drag(driver, 120, 40)
    browser.wait_for_picture(driver, count)
    after, second, _ = shown(driver)
    assert after["target"] == before["target"]
    assert after["eye"] != before["eye"]
    assert distance(after) == pytest.approx(distance(before), rel=1e-9)
    assert not np.array_equal(pixels(first), pixels(second))
    assert_is_the_render_of_its_camera(url, room, after, second)


def test_shift_dragging_pans_and_the_wheel_zooms(driver, url, room):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.actions.wheel_input import ScrollOrigin

    count = open_viewer(driver, url, room)
    before, first, _ = shown(driver)
    browser.drag(driver, 80, -40, shift=True)
    count = browser.wait_for_picture(driver, count)
    panned, second, _ = shown(driver)
    assert panned["target"] != before["target"]
    moved = np.subtract(panned["eye"], before["eye"])
    assert np.allclose(moved, np.subtract(panned["target"], before["target"]))  # eye moves along
    assert not np.array_equal(pixels(first), pixels(second))
    assert_is_the_render_of_its_camera(url, room, panned, second)

    picture = driver.find_element("id", "view")
    ActionChains(driver).scroll_from_origin(ScrollOrigin.from_element(picture), 0, 300).perform()
    browser.wait_for_picture(driver, count)
    zoomed, third, _ = shown(driver)
    assert zoomed["target"] == panned["target"] and distance(zoomed) > 1.4 * distance(panned)
    assert not np.array_equal(pixels(second), pixels(third))
    assert_is_the_render_of_its_camera(url, room, zoomed, third)


def test_a_new_version_of_the_scene_is_shown_and_new_scenes_are_listed(
    driver, url, room, scene_name
):
    count = open_viewer(driver, url, room)
    camera, first, version = shown(driver)
    vertices, _ = MESHES["sphere"]
    with Client(url) as api:
        info = api.update_vertices(room, "sphere", vertices + np.float32([-2.0, 0.0, 0.5]))
        api.put_mesh(scene_name + "-more", "box", *MESHES["box"])
    assert str(info["version"]) != version

    def shows_the_new_version(d):
        shown_version = d.find_element("id", "view").get_attribute("data-version")
        return d.execute_script("return window.viewer.idle()") and shown_version == str(
            info["version"]
        )

    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(driver, 30, poll_frequency=0.05, ignored_exceptions=REBUILT).until(
        shows_the_new_version
    )
    again, second, _ = shown(driver)
    assert again == camera  # the camera stays; the scene moved
    assert not np.array_equal(pixels(first), pixels(second))
    assert_is_the_render_of_its_camera(url, room, camera, second)
    assert browser.wait_for_picture(driver, 0) > count

    def lists_the_new_scene(d):
        options = d.find_elements("css selector", "#scene option")
        return any(o.get_attribute("value") == scene_name + "-more" for o in options)

    WebDriverWait(driver, 30, poll_frequency=0.1, ignored_exceptions=REBUILT).until(
        lists_the_new_scene
    )
    # choosing it (here through the page's address) shows it
    count = browser.wait_for_picture(driver, 0)
    driver.execute_script("location.hash = arguments[0]", f"scene={scene_name}-more&up=z")
    browser.wait_for_picture(driver, count)
    assert driver.find_element("id", "scene").get_attribute("value") == scene_name + "-more"
    camera, png, version = shown(driver)
    assert version == "1"
    assert_is_the_render_of_its_camera(url, scene_name + "-more", camera, png)


def test_without_a_scene_in_its_address_the_page_opens_the_demo(driver, url, scene_name):
    with Client(url) as api:  # this server loads no demo: a scene of that name stands for it
        api.put_mesh("demo", "box", *MESHES["box"])
        api.put_mesh("0-sorts-first-" + scene_name, "box", *MESHES["box"])
    driver.get("about:blank")
    driver.get(f"{url}/")
    browser.wait_for_picture(driver)
    assert driver.find_element("id", "scene").get_attribute("value") == "demo"
    camera, png, _ = shown(driver)
    assert_is_the_render_of_its_camera(url, "demo", camera, png)


def test_when_its_scene_goes_the_page_shows_the_last_changed(driver, url, room, scene_name):
    from selenium.webdriver.support.ui import WebDriverWait

    open_viewer(driver, url, room)
    later = "z-changed-" + scene_name  # neither the demo nor the first listed
    with Client(url) as api:
        api.put_mesh(later, "box", *MESHES["box"])

        def lists(d):
            return later in [
                o.get_attribute("value") for o in d.find_elements("css selector", "#scene option")
            ]

        WebDriverWait(driver, 30, poll_frequency=0.05, ignored_exceptions=REBUILT).until(lists)
        api.delete(room)
    WebDriverWait(driver, 30, poll_frequency=0.05, ignored_exceptions=REBUILT).until(
        lambda d: d.find_element("id", "scene").get_attribute("value") == later
    )
    browser.wait_for_picture(driver)
    camera, png, _ = shown(driver)
    assert_is_the_render_of_its_camera(url, later, camera, png)
    # the page says why it shows another scene, after that scene's picture has come
    assert driver.find_element("id", "notice").text == f"scene {room} is gone; showing {later}"


def test_a_shading_or_up_the_page_does_not_offer_is_ignored(driver, url, room):
    driver.get("about:blank")
    driver.get(f"{url}/#scene={room}&shading=Depth&up=x")
    browser.wait_for_picture(driver)
    assert driver.find_element("id", "shading").get_attribute("value") == "shaded"
    assert driver.find_element("id", "up").get_attribute("value") == "y"
    camera, png, _ = shown(driver)
    assert camera["shading"] == "shaded" and driver.find_element("id", "error").text == ""
    assert_is_the_render_of_its_camera(url, room, camera, png)


def test_when_every_scene_goes_the_page_shows_no_picture(driver, url, room):
    from selenium.webdriver.support.ui import WebDriverWait

    open_viewer(driver, url, room)
    with Client(url) as api:
        for info in api.scenes():
            api.delete(info["scene"])
    WebDriverWait(driver, 30, poll_frequency=0.05).until(
        lambda d: d.find_element("id", "status").text.startswith("no scenes yet")
    )
    picture = driver.find_element("id", "view")
    assert picture.get_attribute("src") in (None, "")
    assert picture.get_attribute("data-camera") is None
    assert driver.find_element("id", "camera").text == ""
    assert driver.find_element("id", "notice").text == f"scene {room} is gone"


def test_on_a_server_with_a_token_the_page_asks_for_it(driver):
    from selenium.webdriver.support.ui import WebDriverWait

    server = ServerProcess({"DACRT_TOKEN": "viewer-token-7", "DACRT_LOAD_DEMO": "true"})
    try:
        url = server.wait_ready()
        driver.get("about:blank")
        driver.get(f"{url}/")
        form = driver.find_element("id", "token-form")
        WebDriverWait(driver, 30, poll_frequency=0.05, ignored_exceptions=REBUILT).until(
            lambda d: form.is_displayed()
        )
        assert "token" in driver.find_element("id", "error").text
        driver.find_element("id", "token").send_keys("viewer-token-7")
        form.submit()
        browser.wait_for_picture(driver)
        camera, png, _ = shown(driver)
        response = httpx.post(
            f"{url}/v1/scenes/demo/render",
            json=camera,
            headers={"Authorization": "Bearer viewer-token-7"},
            timeout=60,
        )
        assert np.array_equal(pixels(response.content), pixels(png))
        assert not form.is_displayed()
    finally:
        driver.execute_script("sessionStorage.clear()")
        server.stop()
