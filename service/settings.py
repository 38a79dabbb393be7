"""Settings, read from the environment with the prefix ``DACRT_`` (e.g. ``DACRT_TOKEN``).

``load_settings`` refuses a DACRT_* variable that names no setting (a typo would silently keep
the default) and names the variable of a bad value, in one line.

Byte sizes are pydantic's ``ByteSize``: plain integers or a unit, ``64MiB``, ``4GiB``, ``500MB``
(``k``, ``kb``, ``MB``, ... are powers of 1000; ``KiB``, ``MiB``, ... of 1024). Counts are positive
integers (``16_000_000`` reads as 16000000).
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Literal

from pydantic import (
    ByteSize,
    Field,
    PositiveInt,
    PrivateAttr,
    SecretStr,
    ValidationError,
    field_validator,
)
from pydantic_settings import BaseSettings, SettingsConfigDict

from .admission import default_budget

KiB, MiB, GiB = 2**10, 2**20, 2**30

Bytes = Annotated[ByteSize, Field(gt=0)]
#: inf would turn a deadline off, which no setting means
Seconds = Annotated[float, Field(gt=0, allow_inf_nan=False)]

PREFIX = "DACRT_"

#: The demo scene shipped inside the package (package data).
PACKAGED_DEMO = Path(__file__).resolve().parent / "data" / "teapot.npz"
LOG_LEVELS = ("critical", "error", "warning", "info", "debug")


class Settings(BaseSettings):
    """Everything an operator can set. Defaults suit one machine serving a few large scenes."""

    model_config = SettingsConfigDict(env_prefix=PREFIX, frozen=True, extra="ignore")

    host: str = "127.0.0.1"  #: bind address of ``python -m service``
    port: int = Field(8000, ge=0, le=65535)  #: port of ``python -m service``
    #: names the ``Host`` header may give, comma-separated (``*``: any); None: the loopback names
    #: for a request that arrives on a loopback address, else any (``service.hosts``)
    allowed_hosts: str | None = None
    #: when set, every /v1 request needs ``Authorization: Bearer <token>``
    token: SecretStr | None = None
    max_body_bytes: Bytes = 512 * MiB  #: largest request body (also the largest decompressed .npz)
    max_rays_per_request: PositiveInt = 16 * MiB  #: most rays in one query
    #: most pixels (width x height) of one picture or depth image (render, camera)
    max_image_pixels: PositiveInt = 4 * MiB
    max_triangles_per_scene: PositiveInt = 32 * MiB  #: most triangles in one scene
    max_meshes_per_scene: PositiveInt = 4096  #: most meshes (instances included) in one scene
    #: total bytes of all scenes: vertices and faces, and the engine's 80 bytes a placed triangle
    max_scene_bytes: Bytes = 4 * GiB
    max_hits: PositiveInt = 1024  #: largest ``max_hits`` of a hits query
    #: largest hit buffers of one hits query: rays x (max_hits + 1) x 48 bytes
    #: (``footprint.HIT_SLOT_BYTES``: the engine's lists and the answer's keys of a filled slot)
    max_hits_bytes: Bytes = 2 * GiB
    max_patterns: PositiveInt = 64  #: most scan patterns (``PUT /v1/patterns/{name}``) held
    max_pattern_rays: PositiveInt = 1 * MiB  #: most rays of one scan pattern
    max_rig_sensors: PositiveInt = 1024  #: most sensors in one rig (``POST .../sensors``)
    threads: int | None = Field(None, gt=0)  #: engine threads per query (None: every core)
    #: .npz (vertices, faces) for the demo scene; None: the teapot shipped with the package
    demo_scene: Path | None = None
    demo_name: str = "demo"  #: name of the demo scene
    load_demo: bool = False  #: load the demo scene at start (``python -m service`` turns it on)
    header_timeout: Seconds = 10  #: seconds a connection has to send a request's headers
    body_timeout: Seconds = 600  #: seconds a request has to send its whole body
    #: seconds a request's body may go without a byte while the server reads it
    body_idle_timeout: Seconds = 30
    #: seconds an answer may wait on a client that reads none of it; then the connection ends
    answer_idle_timeout: Seconds = 30
    #: open connections; more are answered 503, except GET /health and /metrics
    max_connections: PositiveInt = 100
    #: open connections from one client address; more are answered 503, except GET /health and
    #: /metrics (behind a reverse proxy every client has the proxy's address)
    max_connections_per_client: PositiveInt = 32
    #: folder where every scene change is made durable before it is acknowledged; None: memory only
    data_dir: Path | None = None
    #: file holding the bearer token (instead of DACRT_TOKEN); read by ``load_settings``
    token_file: Path | None = None
    #: Numba's compiled kernels (``dacrt.cache.use_cache_dir``, at the server's start)
    cache_dir: Path | None = None
    log_level: Literal[LOG_LEVELS] = "info"  #: the service's and uvicorn's log level
    #: address of a dask scheduler (``tcp://host:8786``): queries of at least ``dask_min_rays``
    #: rays are traced on its workers (needs the ``dask`` extra); None: every query in process
    dask_scheduler: str | None = None
    dask_min_rays: PositiveInt = 1 * MiB  #: fewest rays of a query traced on the dask cluster
    #: seconds a query waits for each thing it asks of the dask cluster (sending a scene version's
    #: triangles, its batch); past them, or when the cluster fails, it is traced in process
    dask_timeout: Seconds = 30
    #: bytes that all requests in flight may hold at their peak (bodies, rays, the engine's work,
    #: answers); None: a quarter of the machine's memory (``service.admission``)
    max_inflight_bytes: Bytes | None = None
    #: seconds a request waits for room in that budget before it is answered 503
    admission_wait: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 5
    #: where queries and sensors are traced: "cpu", or "cuda" (``dacrt.cuda``: on scenes without
    #: deforming meshes, no ?stats; the CPU traces the rest); "cuda" is refused at start where no
    #: GPU (nor Numba's CUDA simulator) is available
    device: Literal["cpu", "cuda"] = "cpu"
    #: the command-line option each setting given there came from (``service.cli``), which a
    #: message names instead of its variable
    _options: dict[str, str] = PrivateAttr(default_factory=dict)

    @field_validator("host", mode="before")
    @classmethod
    def _host_given(cls, value: object) -> object:
        # an empty address binds every interface, which only 0.0.0.0 should ask for
        if value == "":
            raise ValueError("give an address to listen on (0.0.0.0 for every interface)")
        return value

    @field_validator("data_dir", "cache_dir", "demo_scene", "dask_scheduler", mode="before")
    @classmethod
    def _empty_is_unset(cls, value: object) -> object:
        # as an env file leaves an unset ${VAR}; pydantic would read a path "" as ".", the
        # working directory
        return None if value == "" else value

    @field_validator("token", "token_file", mode="before")
    @classmethod
    def _token_given(cls, value: object) -> object:
        # read as unset, a DACRT_TOKEN=$SECRET whose SECRET is unset would serve without a token
        if value == "":
            raise ValueError(
                "give a value, or leave the variable unset for a server without a token"
            )
        return value

    @field_validator("demo_name")
    @classmethod
    def _scene_name(cls, value: str) -> str:
        from .errors import Invalid
        from .store import check_name  # the engine's import, only for a name that is set

        try:
            return check_name("scene", value)
        except Invalid as error:
            raise ValueError(error.detail) from None

    @field_validator("threads")
    @classmethod
    def _threads_in_the_pool(cls, value: int | None) -> int | None:
        from dacrt.chunks import POOL_THREADS  # the engine's import, only for a count that is set

        if value is not None and value > POOL_THREADS:
            raise ValueError(
                f"at most {POOL_THREADS}, the most threads the engine runs on this machine "
                "(dacrt.chunks.POOL_THREADS)"
            )
        return value

    @field_validator("max_inflight_bytes")
    @classmethod
    def _budget_serves_a_request(cls, value: ByteSize | None) -> ByteSize | None:
        from .footprint import MIN_BUDGET_BYTES  # the engine's import, only for a budget set

        if value is not None and value < MIN_BUDGET_BYTES:
            raise ValueError(
                f"at least {MIN_BUDGET_BYTES // MiB}MiB, what a one-ray query answered in JSON "
                "holds (service.footprint.MIN_BUDGET_BYTES)"
            )
        return value

    @field_validator("token")
    @classmethod
    def _presentable_token(cls, value: SecretStr | None) -> SecretStr | None:
        problem = None if value is None else token_problem(value.get_secret_value())
        if problem is not None:
            raise ValueError(problem)
        return value

    @field_validator("log_level", mode="before")
    @classmethod
    def _lower_case_level(cls, value: object) -> object:
        return value.lower() if isinstance(value, str) else value

    @field_validator("allowed_hosts")
    @classmethod
    def _host_names(cls, value: str | None) -> str | None:
        if value is None:
            return None
        names = [name.strip() for name in value.split(",")]
        if not all(names):
            raise ValueError("give host names separated by commas, or *")
        return ",".join(names)

    def given(self, field: str) -> str:
        """A setting as the user gave it, for a message: ``--port 8080`` or ``DACRT_PORT=8080``."""
        return named(field, getattr(self, field), self._options)

    def host_names(self) -> tuple[str, ...] | None:
        """The names a request's ``Host`` may give; None: by the address it arrives on
        (``service.hosts``)."""
        if self.allowed_hosts is None:
            return None
        return tuple(name.lower().strip("[]") for name in self.allowed_hosts.split(","))

    def demo_path(self) -> Path:
        """The demo scene file to load: DACRT_DEMO_SCENE (relative to the working directory) or
        the packaged teapot; FileNotFoundError saying where it looked."""
        path = PACKAGED_DEMO if self.demo_scene is None else self.demo_scene.expanduser()
        resolved = path.resolve()
        if not resolved.is_file():
            where = "DACRT_DEMO_SCENE" if self.demo_scene is not None else "the package data"
            raise FileNotFoundError(f"no demo scene at {resolved} (from {where})")
        return resolved

    def limits(self) -> dict[str, int]:
        """The limits in force, as shown by /v1/capabilities."""
        return {
            "max_body_bytes": self.max_body_bytes,
            "max_rays_per_request": self.max_rays_per_request,
            "max_image_pixels": self.max_image_pixels,
            "max_triangles_per_scene": self.max_triangles_per_scene,
            "max_meshes_per_scene": self.max_meshes_per_scene,
            "max_scene_bytes": self.max_scene_bytes,
            "max_hits": self.max_hits,
            "max_hits_bytes": self.max_hits_bytes,
            "max_patterns": self.max_patterns,
            "max_pattern_rays": self.max_pattern_rays,
            "max_rig_sensors": self.max_rig_sensors,
            "max_inflight_bytes": self.inflight_budget(),
        }

    def inflight_budget(self) -> int:
        """DACRT_MAX_INFLIGHT_BYTES, or its default: a quarter of the machine's memory."""
        return self.max_inflight_bytes or default_budget()


class SettingsError(ValueError):
    """A DACRT_* environment variable that names no setting or has a bad value (one line)."""


def variable(field: str) -> str:
    """The environment variable of a setting: ``max_body_bytes`` -> ``DACRT_MAX_BODY_BYTES``."""
    return PREFIX + field.upper()


def named(field: str, value: object, options: Mapping[str, str]) -> str:
    """``--port 'abc'`` where ``options`` has the setting's option, else ``DACRT_PORT='abc'``."""
    shown = str(value) if isinstance(value, Path) else value
    if field in options:
        return f"{options[field]} {shown!r}"
    return f"{variable(field)}={shown!r}"


def check_names(environ: Mapping[str, str]) -> None:
    """Refuse DACRT_* variables that name no setting: a typo would silently keep the default."""
    fields = list(Settings.model_fields)
    for name in sorted(environ):
        field = name.lower().removeprefix(PREFIX.lower())
        if name.upper().startswith(PREFIX) and field not in fields:
            close = difflib.get_close_matches(field, fields, n=1)  # not on the shared prefix
            hint = (
                f"did you mean {variable(close[0])}?"
                if close
                else "known: " + ", ".join(variable(f) for f in fields)
            )
            raise SettingsError(f"unknown setting {name}; {hint}")


def describe(error: ValidationError, options: Mapping[str, str] | None = None) -> str:
    """One line naming each bad setting as it was given, e.g. ``DACRT_PORT='x': Input should be
    ...``, or ``--port 'x': ...`` for one of ``options`` (setting -> command-line option)."""
    parts = []
    for item in error.errors():
        field = str(item["loc"][0]) if item["loc"] else ""
        if field == "token":  # never echo the secret
            parts.append(f"{variable(field)}: {item['msg']}")
        else:
            parts.append(f"{named(field, item.get('input'), options or {})}: {item['msg']}")
    return "bad setting " + "; ".join(parts)


def load_settings(options: Mapping[str, str] | None = None, **overrides: object) -> Settings:
    """Settings from the environment (and ``overrides``), or SettingsError naming the variable,
    or the command-line option of ``options`` (setting -> option) that gave the override."""
    options = {field: option for field, option in (options or {}).items() if field in overrides}
    check_names(os.environ)
    try:
        settings = Settings(**overrides)
    except ValidationError as error:
        raise SettingsError(describe(error, options)) from None
    settings._options = options
    check_device(settings.device)
    if settings.token_file is None:
        return settings
    if settings.token is not None:
        given = options.get("token_file", variable("token_file"))
        raise SettingsError(f"set DACRT_TOKEN or {given}, not both")
    return settings.model_copy(update={"token": read_token(settings.token_file, options)})


def check_device(device: str) -> None:
    """Refuse DACRT_DEVICE=cuda in one line where the CUDA backend cannot run: no GPU (nor
    Numba's CUDA simulator, NUMBA_ENABLE_CUDASIM=1)."""
    if device == "cpu":
        return
    from dacrt import cuda  # numba.cuda is imported only for this setting

    if not cuda.is_available():
        raise SettingsError("DACRT_DEVICE='cuda': no CUDA GPU is available on this machine")


def token_problem(token: str) -> str | None:
    """Why no client could present ``token`` in an ``Authorization`` header, or None: a header
    value loses surrounding whitespace, and clients differ in how they encode other than
    visible ASCII."""
    if token != token.strip():
        return "the token starts or ends with whitespace, which no Authorization header keeps"
    if not all("!" <= character <= "~" for character in token):
        return "the token holds characters other than visible ASCII (! to ~)"
    return None


def read_token(path: Path, options: Mapping[str, str] | None = None) -> SecretStr:
    """The token in ``path`` (surrounding whitespace removed); SettingsError if unusable, naming
    DACRT_TOKEN_FILE, or ``--token-file`` where ``options`` has it."""
    where = named("token_file", path, options or {})
    try:
        token = path.expanduser().read_text().strip()
    except (OSError, UnicodeDecodeError) as error:
        raise SettingsError(f"{where}: cannot read it ({error})") from None
    if not token:
        raise SettingsError(f"{where} is empty")
    problem = token_problem(token)
    if problem is not None:
        raise SettingsError(f"{where}: {problem}")
    return SecretStr(token)


def load_settings_or_exit(
    options: Mapping[str, str] | None = None, **overrides: object
) -> Settings:
    """``load_settings`` for launchers: a bad environment or option ends the process with one
    line, no traceback (SystemExit prints its message to stderr and exits with status 1)."""
    try:
        return load_settings(options, **overrides)
    except SettingsError as error:
        raise SystemExit(f"dacrt-service: {error}") from None
