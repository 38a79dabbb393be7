"""Settings from DACRT_* environment variables, with sizes in units; unknown names and bad
values refused in one line."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from pydantic import ValidationError
from server_process import ServerProcess
from service_helpers import REPO

import service
from service import hosts
from service.settings import (
    MiB,
    Settings,
    SettingsError,
    check_names,
    load_settings,
    load_settings_or_exit,
    variable,
)


def test_defaults_are_sane(monkeypatch):
    for name in (
        "TOKEN",
        "MAX_BODY_BYTES",
        "MAX_RAYS_PER_REQUEST",
        "MAX_TRIANGLES_PER_SCENE",
        "MAX_SCENE_BYTES",
        "LOAD_DEMO",
        "HOST",
        "PORT",
    ):
        monkeypatch.delenv(f"DACRT_{name}", raising=False)
    settings = Settings()
    assert settings.token is None and settings.load_demo is False
    assert settings.max_body_bytes == 512 * MiB and settings.max_rays_per_request == 16 * MiB
    assert settings.max_triangles_per_scene == 32 * MiB and settings.max_scene_bytes == 4 * 2**30
    assert (settings.host, settings.port) == ("127.0.0.1", 8000)


def test_environment_sets_everything(monkeypatch):
    monkeypatch.setenv("DACRT_TOKEN", "s3cret")
    monkeypatch.setenv("DACRT_MAX_BODY_BYTES", "64MiB")
    monkeypatch.setenv("DACRT_MAX_RAYS_PER_REQUEST", "1000")
    monkeypatch.setenv("DACRT_LOAD_DEMO", "true")
    monkeypatch.setenv("DACRT_PORT", "9001")
    settings = Settings()
    assert settings.token.get_secret_value() == "s3cret" and "s3cret" not in repr(settings)
    assert settings.max_body_bytes == 64 * MiB and settings.max_rays_per_request == 1000
    assert settings.load_demo and settings.port == 9001


def test_an_empty_token_is_refused_not_read_as_no_token(monkeypatch):
    monkeypatch.setenv("DACRT_TOKEN", "")
    with pytest.raises(SettingsError) as refused:
        load_settings()
    assert str(refused.value).startswith("bad setting DACRT_TOKEN: ")
    assert "leave the variable unset" in str(refused.value)


@pytest.mark.parametrize(
    "text, value",
    [
        ("10", 10),
        ("10k", 10_000),  # pydantic's ByteSize: k is 1000, KiB 1024
        ("10KiB", 10240),
        ("2 MiB", 2 * MiB),
        ("1GB", 10**9),
        ("4GiB", 4 * 2**30),
        ("1_000", 1000),
    ],
)
def test_sizes_take_units(text, value):
    assert Settings(max_body_bytes=text).max_body_bytes == value


@pytest.mark.parametrize(
    "field, value",
    [
        ("max_body_bytes", "0"),
        ("max_rays_per_request", "-5"),
        ("max_scene_bytes", "lots"),
        ("port", "70000"),
    ],
)
def test_bad_values_are_refused(field, value):
    with pytest.raises(ValidationError):
        Settings(**{field: value})


@pytest.mark.parametrize(
    "address, allowed, names",
    [
        ("127.0.0.1", None, ("localhost", "127.0.0.1", "::1")),
        ("::1", None, ("localhost", "127.0.0.1", "::1")),
        ("localhost", None, ("localhost", "127.0.0.1", "::1")),
        ("0.0.0.0", None, ("*",)),  # the Dockerfile binds it: what a request arrives on decides
        ("172.17.0.2", None, ("*",)),
        ("127.0.0.1", " Render.example ,[::1]", ("render.example", "::1")),
        ("127.0.0.1", "*", ("*",)),
    ],
)
def test_allowed_hosts_default_to_the_loopback_names_on_a_loopback_address(address, allowed, names):
    given = Settings(allowed_hosts=allowed).host_names()
    assert (given or hosts.default_allowed_hosts(address)) == names


def test_an_empty_allowed_host_is_refused_in_one_line(environ):
    environ(DACRT_ALLOWED_HOSTS="a.example,,b")
    with pytest.raises(SettingsError, match="DACRT_ALLOWED_HOSTS='a.example,,b': .*commas"):
        load_settings()


def test_demo_scene_is_package_data(monkeypatch, tmp_path):
    monkeypatch.delenv("DACRT_DEMO_SCENE", raising=False)
    monkeypatch.chdir(tmp_path)  # whatever the working directory: found in the package
    assert Settings().demo_path() == Path(service.__file__).parent / "data" / "teapot.npz"


def test_a_relative_demo_scene_is_resolved_and_a_missing_one_says_where(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.npz").write_bytes(b"")
    assert Settings(demo_scene="mine.npz").demo_path() == tmp_path / "mine.npz"
    with pytest.raises(FileNotFoundError, match=f"no demo scene at {tmp_path / 'nope.npz'}"):
        Settings(demo_scene="nope.npz").demo_path()


@pytest.fixture
def environ(monkeypatch):
    """Set DACRT_* variables on an environment cleared of the test run's own."""
    for name in list(os.environ):
        if name.upper().startswith("DACRT_"):
            monkeypatch.delenv(name)
    return lambda **variables: [monkeypatch.setenv(k, v) for k, v in variables.items()]


@pytest.mark.parametrize(
    "name, closest",
    [
        ("DACRT_MAX_BODY_BYTE", "DACRT_MAX_BODY_BYTES"),
        ("DACRT_TOKN", "DACRT_TOKEN"),
        ("dacrt_header_timout", "DACRT_HEADER_TIMEOUT"),
    ],
)
def test_unknown_variables_are_refused_with_the_closest_name(name, closest):
    with pytest.raises(SettingsError) as refused:
        check_names({"PATH": "/bin", "DACRT_PORT": "80", name: "1MiB"})
    assert str(refused.value) == f"unknown setting {name}; did you mean {closest}?"


def test_an_unknown_variable_without_a_close_name_lists_the_known_ones():
    with pytest.raises(SettingsError, match=r"^unknown setting DACRT_ZZZ; known: DACRT_HOST, "):
        check_names({"DACRT_ZZZ": "1"})


def test_load_settings_refuses_an_unknown_variable_in_the_environment(environ):
    environ(DACRT_MAX_BODY_BYTE="1MiB")
    with pytest.raises(SettingsError, match="BODY_BYTE; did you mean DACRT_MAX_BODY_BYTES"):
        load_settings()


def test_a_bad_value_names_the_variable_in_one_line(environ):
    environ(DACRT_MAX_BODY_BYTES="lots", DACRT_HEADER_TIMEOUT="0")
    with pytest.raises(SettingsError) as refused:
        load_settings()
    message = str(refused.value)
    assert message.startswith("bad setting ") and "\n" not in message
    assert "DACRT_MAX_BODY_BYTES='lots'" in message and "DACRT_HEADER_TIMEOUT='0'" in message
    assert "max_body_bytes" not in message and "validation error" not in message


def test_the_device_is_the_cpu_by_default_and_cuda_is_refused_in_one_line_without_a_gpu(environ):
    assert load_settings().device == "cpu"
    environ(DACRT_DEVICE="cuda")
    from dacrt import cuda

    if cuda.is_available():  # a GPU, or the simulator: queries are routed to it (test_device)
        assert load_settings().device == "cuda"
    else:
        with pytest.raises(SettingsError, match="^DACRT_DEVICE='cuda': no CUDA GPU[^\n]*$"):
            load_settings()
    environ(DACRT_DEVICE="tpu")
    with pytest.raises(SettingsError, match="DACRT_DEVICE='tpu'"):
        load_settings()


def test_load_settings_reads_the_environment_and_overrides(environ):
    environ(DACRT_MAX_CONNECTIONS="7", DACRT_BODY_TIMEOUT="2.5", DACRT_LOAD_DEMO="false")
    settings = load_settings(load_demo=True)
    assert (settings.max_connections, settings.body_timeout, settings.load_demo) == (7, 2.5, True)
    assert settings.header_timeout == 10  # the default


def test_slow_client_settings_default_under_a_minute_and_a_share_of_the_connections(environ):
    defaults = load_settings()
    assert 0 < defaults.body_idle_timeout <= 60  # nginx closes a body idle for 60 s
    assert defaults.max_connections_per_client < defaults.max_connections
    environ(DACRT_BODY_IDLE_TIMEOUT="1.5", DACRT_MAX_CONNECTIONS_PER_CLIENT="4")
    settings = load_settings()
    assert (settings.body_idle_timeout, settings.max_connections_per_client) == (1.5, 4)
    environ(DACRT_BODY_IDLE_TIMEOUT="0")
    with pytest.raises(SettingsError, match="DACRT_BODY_IDLE_TIMEOUT='0'"):
        load_settings()


def test_launchers_exit_with_the_message(environ):
    environ(DACRT_PORT="x")
    with pytest.raises(SystemExit) as exited:
        load_settings_or_exit()
    assert str(exited.value).startswith("dacrt-service: bad setting DACRT_PORT='x': ")


LAUNCHERS = {
    "python -m service": ["-m", "service"],
    "uvicorn factory": ["-m", "uvicorn", "service.app:create_app", "--factory", "--port", "0"],
}


@pytest.mark.parametrize("launcher", LAUNCHERS)
@pytest.mark.parametrize(
    "variable, value, message",
    [
        (
            "DACRT_MAX_BODY_BYTE",
            "1MiB",
            "unknown setting DACRT_MAX_BODY_BYTE; did you mean DACRT_MAX_BODY_BYTES?",
        ),
        ("DACRT_MAX_BODY_BYTES", "lots", "bad setting DACRT_MAX_BODY_BYTES='lots': "),
        ("DACRT_TOKEN", "abc ", "bad setting DACRT_TOKEN: Value error, the token starts or ends"),
        ("DACRT_HOST", "", "bad setting DACRT_HOST='': "),
    ],
)
def test_the_server_refuses_to_start(launcher, variable, value, message):
    inherited = {k: v for k, v in os.environ.items() if not k.upper().startswith("DACRT_")}
    done = subprocess.run(
        [sys.executable, *LAUNCHERS[launcher]],
        cwd=REPO,
        timeout=120,
        env={**inherited, "PYTHONPATH": str(REPO), variable: value},
        capture_output=True,
        text=True,
    )
    output = (done.stdout + done.stderr).strip()
    assert done.returncode != 0
    assert output.splitlines() == [output] and "Traceback" not in output
    assert output.startswith("dacrt-service: " + message), output


@pytest.mark.parametrize(
    "token, problem",
    [
        ("abc ", "starts or ends with whitespace"),
        ("\tabc", "starts or ends with whitespace"),
        ("p\u00e4ssw\u00f6rd", "other than visible ASCII"),
        ("two words", "other than visible ASCII"),
        ("tok\x7f", "other than visible ASCII"),
    ],
)
def test_a_token_no_client_can_present_is_refused_in_one_line(environ, token, problem):
    environ(DACRT_TOKEN=token)
    with pytest.raises(SettingsError, match=f"^bad setting DACRT_TOKEN: .*{problem}") as caught:
        load_settings()
    assert token.strip() not in str(caught.value)  # the secret is never echoed


def test_a_token_file_is_stripped_but_other_than_visible_ascii_is_refused(environ, tmp_path):
    (tmp_path / "token").write_text(" abc \n")
    environ(DACRT_TOKEN_FILE=str(tmp_path / "token"))
    assert load_settings().token.get_secret_value() == "abc"
    (tmp_path / "token").write_text("p\u00e4ssw\u00f6rd\n")
    with pytest.raises(SettingsError, match="^DACRT_TOKEN_FILE=.*: the token holds characters"):
        load_settings()


def test_every_visible_ascii_token_is_accepted(environ):
    token = "".join(chr(c) for c in range(0x21, 0x7F))
    environ(DACRT_TOKEN=token)
    assert load_settings().token.get_secret_value() == token


def test_the_token_can_come_from_a_file(environ, tmp_path):
    (tmp_path / "token").write_text("s3cret\n")
    environ(DACRT_TOKEN_FILE=str(tmp_path / "token"))
    assert load_settings().token.get_secret_value() == "s3cret"
    environ(DACRT_TOKEN="other")
    with pytest.raises(SettingsError, match="not both"):
        load_settings()


@pytest.mark.parametrize("content", [None, "  \n"], ids=["missing", "empty"])
def test_an_unusable_token_file_is_refused(environ, tmp_path, content):
    if content is not None:
        (tmp_path / "token").write_text(content)
    environ(DACRT_TOKEN_FILE=str(tmp_path / "token"))
    with pytest.raises(SettingsError, match="DACRT_TOKEN_FILE="):
        load_settings()


def test_help_lists_every_option_and_starts_nothing():
    done = subprocess.run(
        [sys.executable, "-m", "service", "--help"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0 and done.stdout.startswith("usage: dacrt-service")
    for option in ("--host", "--port", "--data-dir", "--token-file", "--threads", "--log-level"):
        assert option in done.stdout


def test_help_names_every_setting_without_sending_to_the_readme():
    done = subprocess.run(
        [sys.executable, "-m", "service", "--help"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0
    for field in Settings.model_fields:
        assert variable(field) in done.stdout  # a pip user has no README
    assert "README" not in done.stdout
    # the demo's default as this command has it, not the app factory's
    assert "DACRT_LOAD_DEMO=true" in " ".join(done.stdout.split())


@pytest.mark.parametrize("package", ["uvicorn", "fastapi", "pydantic_settings"])
def test_a_missing_web_stack_is_one_line_naming_the_extra(package):
    hidden = f"import sys; sys.modules[{package!r}] = None; "  # as if not installed
    done = subprocess.run(
        [sys.executable, "-c", hidden + "from service.__main__ import main; main(['--help'])"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.count("\n") == 1
    assert package in done.stderr and "pip install 'dacrt-service[service]'" in done.stderr


def test_options_of_the_command_line_set_the_server(tmp_path):
    (tmp_path / "token").write_text("from-a-file")
    options = ["--data-dir", str(tmp_path / "data"), "--token-file", str(tmp_path / "token")]
    server = ServerProcess(
        {"DACRT_LOG_LEVEL": "info"},
        command=[
            "service",
            "--port",
            "{port}",
            "--log-level",
            "warning",
            "--threads",
            "1",
            *options,
        ],
    )
    try:
        url = server.wait_ready()
        assert httpx.get(f"{url}/v1/scenes").status_code == 401
        headers = {"Authorization": "Bearer from-a-file"}
        capabilities = httpx.get(f"{url}/v1/capabilities", headers=headers).json()
        assert capabilities["threads"] == 1
        assert (tmp_path / "data" / "scenes").is_dir()
        assert "INFO:     service:" not in server.output()
    finally:
        server.stop()


def test_an_empty_host_is_refused_rather_than_bind_every_interface(environ):
    environ(DACRT_HOST="")
    with pytest.raises(SettingsError, match=r"^bad setting DACRT_HOST='': .*0\.0\.0\.0[^\n]*$"):
        load_settings()
    with pytest.raises(SettingsError, match="DACRT_HOST=''"):
        load_settings(host="")  # --host ''


@pytest.mark.parametrize("field", ["data_dir", "cache_dir", "demo_scene"])
def test_an_empty_path_is_unset_not_the_working_directory(environ, field):
    environ(**{variable(field): ""})
    assert getattr(load_settings(), field) is None
    assert getattr(load_settings(**{field: ""}), field) is None  # --data-dir ''


#: The settings an empty value leaves unset (README, "Settings"); it is refused for the others.
EMPTY_IS_UNSET = ("data_dir", "cache_dir", "demo_scene", "dask_scheduler")


@pytest.mark.parametrize("field", list(Settings.model_fields))
def test_an_empty_value_is_unset_or_refused_in_one_line(environ, field):
    environ(**{variable(field): ""})
    if field in EMPTY_IS_UNSET:
        assert getattr(load_settings(), field) is None
        return
    with pytest.raises(SettingsError) as refused:
        load_settings()
    shown = "" if field == "token" else "=''"  # a token is never echoed
    assert str(refused.value).startswith(f"bad setting {variable(field)}{shown}: ")
    assert "\n" not in str(refused.value)


def test_an_empty_data_dir_keeps_the_scenes_in_memory(environ, monkeypatch, tmp_path):
    from service.app import open_data_dir

    monkeypatch.chdir(tmp_path)
    environ(DACRT_DATA_DIR="")
    assert open_data_dir(load_settings()) is None
    assert list(tmp_path.iterdir()) == []


def test_an_empty_token_file_is_refused_without_naming_the_working_directory(environ):
    environ(DACRT_TOKEN_FILE="")
    with pytest.raises(SettingsError) as refused:
        load_settings()
    message = str(refused.value)
    assert message.startswith("bad setting DACRT_TOKEN_FILE='': ") and "\n" not in message
    assert "'.'" not in message and "directory" not in message


@pytest.mark.parametrize("name", ["bad name!", "", "x" * 65, "a\nb", "..", "."])
def test_a_demo_name_that_is_no_scene_name_is_refused_naming_the_variable(environ, name):
    environ(DACRT_DEMO_NAME=name)
    with pytest.raises(SettingsError) as refused:
        load_settings(load_demo=True)
    message = str(refused.value)
    assert message.startswith(f"bad setting DACRT_DEMO_NAME={name!r}: ") and "\n" not in message
    assert "1-64 characters of A-Z a-z 0-9 _ - ." in message


def test_a_demo_name_that_is_a_scene_name_is_taken(environ):
    environ(DACRT_DEMO_NAME="teapot_2.v1")
    assert load_settings().demo_name == "teapot_2.v1"


@pytest.mark.parametrize(
    "name",
    [
        "DACRT_HEADER_TIMEOUT",
        "DACRT_BODY_TIMEOUT",
        "DACRT_BODY_IDLE_TIMEOUT",
        "DACRT_ANSWER_IDLE_TIMEOUT",
        "DACRT_ADMISSION_WAIT",
    ],
)
@pytest.mark.parametrize("value", ["inf", "Infinity", "1e400"])
def test_an_infinite_wait_is_refused_rather_than_turn_a_deadline_off(environ, name, value):
    environ(**{name: value})
    with pytest.raises(SettingsError, match=f"^bad setting {name}='{value}': [^\n]*finite"):
        load_settings()


def test_more_threads_than_the_engine_runs_are_refused_naming_the_bound(environ):
    pool = max(32, 4 * (os.cpu_count() or 1))  # the engine's pool, as README gives it
    environ(DACRT_THREADS=str(pool))
    assert load_settings().threads == pool
    environ(DACRT_THREADS=str(pool + 1))
    with pytest.raises(SettingsError, match=f"DACRT_THREADS='{pool + 1}': .*at most {pool}\\b"):
        load_settings()
    environ(DACRT_THREADS="100000")
    with pytest.raises(SettingsError, match="POOL_THREADS"):
        load_settings()


#: The smallest budget: a JSON answer is written in pieces of 16 MiB (docs/limits.md), and a
#: small request's body and work take the MiB beside it.
SMALLEST_BUDGET = 17 * MiB


@pytest.mark.parametrize("value", ["1", "8MiB", str(SMALLEST_BUDGET - 1)])
def test_a_budget_no_json_query_fits_in_is_refused_naming_the_least(environ, value):
    environ(DACRT_MAX_INFLIGHT_BYTES=value)
    with pytest.raises(SettingsError) as refused:
        load_settings()
    message = str(refused.value)
    assert message.startswith(f"bad setting DACRT_MAX_INFLIGHT_BYTES='{value}': ")
    assert "at least 17MiB" in message and "\n" not in message


def test_the_smallest_budget_is_taken(environ):
    environ(DACRT_MAX_INFLIGHT_BYTES="17MiB")
    assert load_settings().max_inflight_bytes == SMALLEST_BUDGET


def refusal(argv: list[str]) -> str:
    """The one line ``dacrt-service ARGV`` ends its start with."""
    from service.cli import main

    with pytest.raises(SystemExit) as exited:
        main(argv)
    message = str(exited.value)
    assert message.startswith("dacrt-service: ") and "\n" not in message
    return message


@pytest.mark.parametrize(
    "argv, variable, expected",
    [
        (["--port", "abc"], None, "bad setting --port 'abc': Input should be a valid integer"),
        (["--port", "abc"], ("DACRT_PORT", "9000"), "bad setting --port 'abc': "),
        (["--port", "70000"], None, "bad setting --port '70000': Input should be less than"),
        (["--threads", "0"], None, "bad setting --threads '0': Input should be greater than 0"),
        (["--log-level", "loud"], None, "bad setting --log-level 'loud': Input should be"),
        ([], ("DACRT_PORT", "abc"), "bad setting DACRT_PORT='abc': Input should be"),
    ],
    ids=["port", "port over its variable", "port range", "threads", "log level", "variable"],
)
def test_a_bad_value_is_named_as_the_user_gave_it(environ, argv, variable, expected):
    """An option names the option, not the variable the user never set."""
    if variable is not None:
        environ(**dict([variable]))
    message = refusal(argv)
    assert message.startswith("dacrt-service: " + expected), message
    if argv:
        assert "DACRT_" not in message


def test_a_taken_port_and_an_unusable_folder_are_named_as_the_user_gave_them(environ, tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        message = refusal(["--port", str(port)])
        assert message.startswith(f"dacrt-service: DACRT_HOST='127.0.0.1', --port {port}: ")
        assert "cannot listen there" in message
        environ(DACRT_PORT=str(port))
        assert refusal([]).startswith(f"dacrt-service: DACRT_HOST='127.0.0.1', DACRT_PORT={port}:")
    folder = tmp_path / "a-file"
    folder.write_text("not a folder")
    message = refusal(["--port", "0", "--data-dir", str(folder)])
    assert message.startswith(f"dacrt-service: --data-dir {str(folder)!r}: the data folder cannot")
    token = tmp_path / "token"
    message = refusal(["--port", "0", "--token-file", str(token)])
    assert message == f"dacrt-service: --token-file {str(token)!r}: cannot read it " + (
        f"([Errno 2] No such file or directory: {str(token)!r})"
    )
    environ(DACRT_TOKEN="abc")
    token.write_text("def")
    assert refusal(["--token-file", str(token)]).endswith(
        "set DACRT_TOKEN or --token-file, not both"
    )
