"""Ray, the engine for work beyond one process (docs/SCALING.md): rollout actors, DAgger collectors,
retraining tasks and Tune sweeps all reach it through `ray_session`.

Ray is an optional extra (`pip install 'imitation-mcap[ray]'`): nothing imports it until a
command asks for workers, so the single-machine path never pays its import or its start-up.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from imitation.errors import ImitationError

LOCAL = "local"
INSTALL_HINT = "pip install 'imitation-mcap[ray]'"
DRIVER_DIRECTORY = "IMITATION_DRIVER_DIRECTORY"  # where the command runs, for its workers
CONNECT_SECONDS = 10  # for a cluster's address to accept a connection
RETRIES = 3  # how often Ray restarts a dead worker (or reruns a dead task) before the run fails


@dataclass(frozen=True)
class Workers:
    """`--workers N --ray-address ADDR [--cpus C]`: N Ray workers on the cluster at ADDR ("local":
    a private Ray of C CPUs on this machine, every core by default)."""

    count: int
    address: str = LOCAL
    cpus: int | None = None

    def __post_init__(self) -> None:
        if self.count < 1:
            raise ImitationError(f"--workers must be at least 1, got {self.count}")
        if self.cpus is not None and self.cpus < 1:
            raise ImitationError(f"--cpus must be at least 1, got {self.cpus}")

    def session(self) -> contextlib.AbstractContextManager[ModuleType]:
        return ray_session(self.address, num_cpus=self.cpus)


def requested_workers(count: int | None, address: str, cpus: int | None) -> Workers | None:
    """The `Workers` that `--workers N --ray-address ADDR --cpus C` ask for, or None to run in this process."""
    if count is None:
        if address != LOCAL or cpus is not None:
            raise ImitationError("--ray-address and --cpus go with --workers N")
        return None
    return Workers(count, address, cpus)


def worker_session(workers: Workers | None) -> contextlib.AbstractContextManager[ModuleType | None]:
    """`workers`' Ray session for the block, or nothing to connect to when the work stays in this process."""
    return workers.session() if workers is not None else contextlib.nullcontext()


def require_ray() -> ModuleType:
    """The `ray` module, or a one-line error saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ImitationError(f"--workers needs Ray, which is not installed: {INSTALL_HINT}") from None
    return ray


@contextlib.contextmanager
def ray_session(address: str = LOCAL, *, num_cpus: int | None = None) -> Iterator[ModuleType]:
    """Ray, connected for the block.

    `address` "local" starts a private Ray in this process tree (of `num_cpus` CPUs; by
    default every core), shut down at the end; "auto" joins the cluster this machine belongs to
    (`ray start` ran here), and "HOST:PORT" or "ray://HOST:PORT" the cluster at that address,
    left running. A session already connected (a sweep's trial, a test) is reused as it is."""
    ray = require_ray()
    if ray.is_initialized():
        yield ray
        return
    # Ray puts the directory the driver connects from first on every worker's import path: a
    # cli.py or imitation/ in the folder the user runs from would be what the workers import.
    # Connecting from the folder that holds this package makes that the code the driver runs;
    # each worker then moves to the user's folder (`enter_driver_directory`).
    runtime_env = {
        "env_vars": {DRIVER_DIRECTORY: os.getcwd()},
        "worker_process_setup_hook": f"{__name__}.enter_driver_directory",
    }
    with contextlib.chdir(Path(__file__).resolve().parent.parent):
        _connect(ray, address, num_cpus, runtime_env)
    try:
        yield ray
    finally:
        ray.shutdown()


def enter_driver_directory() -> None:
    """Every worker's first step (Ray's worker_process_setup_hook): work in the folder the
    command was run from, as the driver does, so that relative paths mean what the user meant
    (on another machine of a cluster, where that folder may not exist, it stays where Ray put it)."""
    with contextlib.suppress(KeyError, OSError):
        os.chdir(os.environ[DRIVER_DIRECTORY])


def _connect(ray: ModuleType, address: str, num_cpus: int | None, runtime_env: dict[str, Any]) -> None:
    if address == LOCAL:
        # Ray's workers would otherwise start torch with a thread per core each, and the actors
        # of one machine would compete for its cores.
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        # Ray picks token authentication for a local cluster itself and says so on stderr at
        # every start: a notice, not a problem of the run's.
        logging.getLogger("ray._private.authentication.authentication_token_setup").setLevel(logging.ERROR)
        ray.init(
            num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, configure_logging=False, runtime_env=runtime_env
        )
    else:
        _check_reachable(address)
        try:
            ray.init(address=address, log_to_driver=False, configure_logging=False, runtime_env=runtime_env)
        except (ConnectionError, ValueError, RuntimeError) as error:
            raise ImitationError(f"--ray-address {address}: cannot connect to a Ray cluster ({error})") from None


def _check_reachable(address: str) -> None:
    """Refuse a HOST:PORT (or ray://HOST:PORT) where nothing accepts a connection: Ray itself
    retries such an address for minutes, saying nothing the user sees."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return  # "auto", or a form Ray resolves itself
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_SECONDS):
            pass
    except OSError as error:
        raise ImitationError(
            f"--ray-address {address}: nothing answers there ({error.strerror or error}); start the cluster (`ray start "
            "--head`), or run on this machine with --ray-address local"
        ) from None


def ray_get(ray: ModuleType, reference: Any) -> Any:
    """`ray.get(reference)`, with an ImitationError raised in a worker re-raised here as the one
    line it is (Ray wraps it with the worker's traceback)."""
    try:
        return ray.get(reference)
    except ray.exceptions.RayTaskError as error:
        if isinstance(error.cause, ImitationError):
            raise ImitationError(str(error.cause)) from None
        raise
