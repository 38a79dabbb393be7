"""One server per data folder (DACRT_DATA_DIR): a second app or server on a folder that another
holds is refused in one line naming the folder and the holder's pid, before it reads anything
there, also after the folder's file ``lock`` was removed; once the holder stops, or is killed
with SIGKILL, the next one starts. A folder that cannot be locked ends the start with one line,
and a real server on a port that is taken ends its start before it opens its data folder."""

from __future__ import annotations

import errno
import fcntl
import os
import socket
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import in_process
import pytest
from server_process import ServerProcess
from service_helpers import NPZ, grid, npz_bytes

from service import app as app_module
from service import persistence
from service.app import open_data_dir
from service.settings import Settings

EXIT_SECONDS = 120  #: a refused server only imports the service before it ends


def refusal(data: Path, pid: int) -> str:
    """The line that refuses a folder held by process ``pid`` of this machine."""
    return (
        f"dacrt-service: DACRT_DATA_DIR={str(data)!r}: the data folder is in use by pid {pid} on "
        f"{socket.gethostname()}, which holds {data / 'lock'}: a data folder serves one server "
        "at a time"
    )


def upload(http: httpx.Client, scene: str, mesh: str) -> None:
    vertices, faces = grid(4)
    body = npz_bytes(vertices=vertices, faces=faces)
    response = http.put(f"/v1/scenes/{scene}/meshes/{mesh}", content=body, headers=NPZ)
    assert response.status_code in (200, 201), response.text


@contextmanager
def serving(data: Path, monkeypatch) -> Iterator[httpx.Client]:
    """The app in process over ``data``; its warm-up compiles nothing (no rays are traced)."""
    monkeypatch.setattr(app_module.warmup, "warm_up", lambda *args, **kwargs: 0.0)
    with in_process.serve(Settings(token=None, load_demo=False, data_dir=data)) as http:
        yield http


def test_a_second_app_on_a_held_folder_is_refused_until_the_first_stops(tmp_path, monkeypatch):
    data = tmp_path / "data"
    with serving(data, monkeypatch) as http:
        upload(http, "s", "a")
        with pytest.raises(SystemExit) as refused:
            open_data_dir(Settings(data_dir=data))
        assert str(refused.value) == refusal(data, os.getpid())
    with serving(data, monkeypatch) as http:  # the first app's stop released the folder
        assert http.get("/v1/scenes/s").json()["version"] == 1


def test_a_file_system_without_flock_ends_the_start_with_one_line(tmp_path, monkeypatch):
    def no_flock(file, operation) -> None:
        raise OSError(errno.ENOLCK, os.strerror(errno.ENOLCK))

    monkeypatch.setattr(persistence.fcntl, "flock", no_flock)
    data = tmp_path / "data"
    with pytest.raises(SystemExit) as exited:
        open_data_dir(Settings(data_dir=data))
    assert str(exited.value) == (
        f"dacrt-service: DACRT_DATA_DIR={str(data)!r}: the data folder cannot be locked (flock on "
        f"{data}): [Errno {errno.ENOLCK}] {os.strerror(errno.ENOLCK)}"
    )


def test_a_file_system_that_locks_only_files_open_for_writing_is_locked(tmp_path, monkeypatch):
    flock = fcntl.flock

    def nfs_flock(file, operation) -> None:
        # as NFS: EBADF for a file open read-only; a folder's flock is the host's own
        fd = file if isinstance(file, int) else file.fileno()
        read_only = fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE == os.O_RDONLY
        if read_only and stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(errno.EBADF, os.strerror(errno.EBADF))
        flock(file, operation)

    monkeypatch.setattr(persistence.fcntl, "flock", nfs_flock)
    data = tmp_path / "data"
    journal = open_data_dir(Settings(data_dir=data))
    with pytest.raises(SystemExit) as refused:
        open_data_dir(Settings(data_dir=data))
    assert str(refused.value) == refusal(data, os.getpid())
    journal.close()
    open_data_dir(Settings(data_dir=data)).close()


def test_a_removed_lock_file_does_not_let_a_second_app_in(tmp_path, monkeypatch):
    """An operator may remove the file ``lock`` (a "stale" lock): the folder stays held, and the
    second app is refused before it reads or writes anything there."""
    data = tmp_path / "data"
    with serving(data, monkeypatch) as http:
        upload(http, "s", "a")
        (data / "lock").unlink()
        with pytest.raises(SystemExit) as refused:
            open_data_dir(Settings(data_dir=data))
        assert str(refused.value) == (
            f"dacrt-service: DACRT_DATA_DIR={str(data)!r}: the data folder is in use by another "
            f"process, which holds {data}: a data folder serves one server at a time"
        )
        assert not (data / "lock").exists()  # the refused app created nothing there
        (data / "lock").write_text("pid 12345 on elsewhere\n")  # a name written again is given
        with pytest.raises(SystemExit) as refused:
            open_data_dir(Settings(data_dir=data))
        assert "in use by pid 12345 on elsewhere, which holds" in str(refused.value)
        assert http.put("/v1/scenes/s/meshes/a/mask", json={"mask": 1}).json()["version"] == 2
    with serving(data, monkeypatch) as http:
        assert http.get("/v1/scenes/s/meshes/a").json()["mask"] == 1
    assert (data / "lock").read_text() == f"pid {os.getpid()} on {socket.gethostname()}\n"


def test_a_folder_that_cannot_hold_its_lock_file_ends_the_start_with_one_line(tmp_path):
    data = tmp_path / "data"
    (data / "lock").mkdir(parents=True)
    with pytest.raises(SystemExit) as exited:
        open_data_dir(Settings(data_dir=data))
    message = str(exited.value)
    assert message.startswith(
        f"dacrt-service: DACRT_DATA_DIR={str(data)!r}: the data folder cannot be written: "
        f"[Errno {errno.EISDIR}] {os.strerror(errno.EISDIR)}"
    )
    assert "\n" not in message


def refused_line(server: ServerProcess) -> str:
    """The last line of a server that ended its start, which must have exited with status 1."""
    server.process.wait(timeout=EXIT_SECONDS)
    output = server.output()
    assert server.process.returncode == 1, output
    assert "data: restored" not in output  # refused before it read the folder
    return output.strip().splitlines()[-1]


def test_a_second_server_is_refused_and_the_next_starts_after_a_sigkill(tmp_path):
    data = tmp_path / "data"
    env = {"DACRT_DATA_DIR": str(data)}
    first = ServerProcess(env)
    servers = [first]
    try:
        with httpx.Client(base_url=first.wait_ready(), timeout=30) as http:
            upload(http, "s", "a")
        second = ServerProcess(env)
        servers.append(second)
        assert refused_line(second) == refusal(data, first.process.pid)

        other = tmp_path / "other"
        taken = ServerProcess({"DACRT_DATA_DIR": str(other), "DACRT_PORT": str(first.port)})
        servers.append(taken)
        assert refused_line(taken).startswith(
            f"dacrt-service: DACRT_HOST='127.0.0.1', DACRT_PORT={first.port}: cannot listen "
            f"there: [Errno {errno.EADDRINUSE}]"
        )
        assert not other.exists()  # the port is checked before the data folder is opened

        first.kill()  # the OS releases its lock
        third = ServerProcess(env)
        servers.append(third)
        with httpx.Client(base_url=third.wait_ready(), timeout=30) as http:
            assert http.get("/v1/scenes/s").json()["version"] == 1
        assert (data / "lock").read_text() == f"pid {third.process.pid} on {socket.gethostname()}\n"
    finally:
        for server in servers:
            server.stop()
