"""Where brl's independent tasks run: in this process, in local worker processes, or on a Ray cluster.

One seam for every command that fans out (bench episodes, training seeds, sweeps):

    for index, result in run_tasks(fn, items, executor="ray", workers=2, setup=make_state):
        ...   # results arrive as tasks finish, in any order; `index` is the item's position in `items`

* `fn(item)` runs each item; with `setup`, `fn(state, item)` gets the state that `setup()` built once per worker
  process (and per `run_tasks` call), e.g. a cache of towns' worlds. `fn` and `setup` must pickle (module-level
  functions, `functools.partial` of them, dataclasses), and so must items and results.
* Inside a task, `report(message)` sends a picklable message to the driver's `on_report` callback (progress).
* executor "local": `workers` = 1 runs in this process; more runs a pool of spawned processes.
* executor "ray": each item is one Ray task (1 CPU) submitted at once; Ray schedules them on every CPU of the
  cluster. A task whose worker process dies is run again (`max_retries`), so the outcome equals an uninterrupted
  run as long as tasks are deterministic; an exception raised by `fn` is not retried and reaches the driver as
  itself. Stopping the iteration (Ctrl-C, an exception in the caller, `close()`) cancels outstanding tasks.
  Ray is imported only here, only for this executor (`pip install 'brl[ray]'`).

Where Ray runs: `ray_address` None joins a running cluster if there is one (Ray's "auto": `RAY_ADDRESS`, the
last `ray start`, a Ray instance on this machine), else starts a local instance with `workers` CPUs (all the
machine's when `workers` is 1); "auto" requires a running cluster, "local" always starts a local instance, and
HOST:PORT joins that cluster's head (an unreachable address is a one-line `BrlInputError` within seconds).
Tasks run the brl installed on the workers (the project's Docker image on KubeRay), with the driver's file paths:
inputs such as model files and outputs written by workers need a filesystem every node mounts at the same path.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import socket
import uuid
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from brlcli.errors import BrlInputError

EXECUTORS = ("local", "ray")
KILL_FIRST_TRY_ENV = "BRL_TEST_KILL_FIRST_TRY"
"""Test hook (Ray executor): with this variable set to a directory, the first task attempt of a run makes its worker
process exit abruptly (os._exit), once per directory (a marker file `killed` records it)."""

_NO_SETUP = object()
_STATE: tuple[str, Any] | None = None  # (run token, state built by setup) of this worker process
_REPORT: Callable[[Any], None] | None = None  # where report() sends messages in this process


def report(message: Any) -> None:
    """Send a progress message from inside a task to the driver's `on_report` (no-op without one)."""
    if _REPORT is not None:
        _REPORT(message)


class Executor:
    """Runs tasks locally or on Ray; `connect()` validates and joins (or starts) Ray before anything is written."""

    def __init__(self, kind: str = "local", workers: int = 1, ray_address: str | None = None,
                 max_retries: int = 3) -> None:
        if kind not in EXECUTORS:
            raise BrlInputError(f"unknown executor '{kind}'; choose from {', '.join(EXECUTORS)}")
        if workers < 1:
            raise BrlInputError("--workers must be at least 1")
        if ray_address is not None and kind != "ray":
            raise BrlInputError("--ray-address needs --executor ray")
        if max_retries < 0:
            raise BrlInputError("max_retries must be >= 0")
        self.kind = kind
        self.workers = workers
        self.ray_address = ray_address
        self.max_retries = max_retries
        self._owns_ray = False
        self._connected = False

    def connect(self) -> Executor:
        """Import and join (or start) Ray for the ray executor; a one-line BrlInputError if that is impossible."""
        if self.kind == "ray" and not self._connected:
            self._owns_ray = _connect_ray(self.ray_address, self.workers)
        self._connected = True
        return self

    def close(self) -> None:
        """Shut down the Ray connection (and the local instance) this executor started; idempotent."""
        if self._owns_ray:
            import ray

            ray.shutdown()
            self._owns_ray = False
        self._connected = False

    def __enter__(self) -> Executor:
        return self.connect()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def describe(self) -> str:
        """Where tasks run, for progress lines: 'local, 2 processes' or 'ray, 8 CPUs on 2 nodes'."""
        if self.kind == "local":
            return f"local, {self.workers} process{'es' if self.workers > 1 else ''}"
        self.connect()
        import ray

        cpus = int(ray.cluster_resources().get("CPU", 0))
        nodes = sum(1 for n in ray.nodes() if n.get("Alive"))
        return f"ray, {cpus} CPU{'s' if cpus != 1 else ''} on {nodes} node{'s' if nodes != 1 else ''}"

    def map(self, fn: Callable[..., Any], items: Sequence[Any], *, setup: Callable[[], Any] | None = None,
            on_report: Callable[[Any], None] | None = None) -> Iterator[tuple[int, Any]]:
        """(index, fn(item)) for every item, as tasks finish (see the module docstring)."""
        items = list(items)
        if not items:
            return
        self.connect()
        token = uuid.uuid4().hex
        if self.kind == "ray":
            yield from _map_ray(fn, items, setup, on_report, token, self.max_retries)
        elif self.workers <= 1 or len(items) == 1:
            yield from _map_inline(fn, items, setup, on_report, token)
        else:
            yield from _map_pool(fn, items, setup, on_report, token, min(self.workers, len(items)))


def run_tasks(fn: Callable[..., Any], items: Sequence[Any], *, executor: str | Executor = "local",
              workers: int = 1, ray_address: str | None = None, setup: Callable[[], Any] | None = None,
              on_report: Callable[[Any], None] | None = None, max_retries: int = 3) -> Iterator[tuple[int, Any]]:
    """Run fn on every item (see the module docstring); yields (index, result) as tasks finish.

    `executor` is "local", "ray" or an `Executor` (connected or not; it is left open for the caller to close).
    """
    if isinstance(executor, Executor):
        yield from executor.map(fn, items, setup=setup, on_report=on_report)
        return
    with Executor(executor, workers, ray_address, max_retries) as ex:
        yield from ex.map(fn, items, setup=setup, on_report=on_report)


# --- worker side -----------------------------------------------------------------------------------------------


def _worker_state(token: str, setup: Callable[[], Any] | None) -> Any:
    """The state of this run in this worker process, built by `setup` on its first task (older runs' dropped)."""
    global _STATE
    if _STATE is None or _STATE[0] != token:
        _close_state()
        _STATE = (token, setup() if setup is not None else _NO_SETUP)
    return _STATE[1]


def _close_state() -> None:
    global _STATE
    if _STATE is not None and hasattr(_STATE[1], "close"):
        _STATE[1].close()
    _STATE = None


def _call(fn: Callable[..., Any], state: Any, item: Any) -> Any:
    return fn(item) if state is _NO_SETUP else fn(state, item)


def _pool_init(token: str, setup: Callable[[], Any] | None, queue: Any) -> None:
    global _REPORT
    _REPORT = queue.put if queue is not None else None
    _worker_state(token, setup)


def _pool_task(args: tuple[Callable[..., Any], str, int, Any]) -> tuple[int, Any]:
    fn, token, index, item = args
    return index, _call(fn, _worker_state(token, None), item)


def _ray_task(fn: Callable[..., Any], setup: Callable[[], Any] | None, token: str, item: Any, queue: Any,
              kill_dir: str | None) -> Any:
    global _REPORT
    if kill_dir:
        try:
            fd = os.open(Path(kill_dir) / "killed", os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            pass
        else:
            os.close(fd)
            os._exit(1)
    _REPORT = queue.put if queue is not None else None
    try:
        return _call(fn, _worker_state(token, setup), item)
    finally:
        _REPORT = None


# --- driver side -----------------------------------------------------------------------------------------------


def _map_inline(fn: Callable[..., Any], items: list[Any], setup: Callable[[], Any] | None,
                on_report: Callable[[Any], None] | None, token: str) -> Iterator[tuple[int, Any]]:
    global _REPORT, _STATE
    saved_report, saved_state = _REPORT, _STATE
    _STATE = None
    state = _worker_state(token, setup)
    try:
        for i, item in enumerate(items):
            _REPORT = on_report
            try:
                result = _call(fn, state, item)
            finally:
                _REPORT = saved_report
            yield i, result
    finally:
        _close_state()
        _REPORT, _STATE = saved_report, saved_state


def _map_pool(fn: Callable[..., Any], items: list[Any], setup: Callable[[], Any] | None,
              on_report: Callable[[Any], None] | None, token: str, processes: int) -> Iterator[tuple[int, Any]]:
    import queue as queue_mod

    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")  # one BLAS thread per worker process: no oversubscription
    ctx = mp.get_context("spawn")
    manager = ctx.Manager() if on_report is not None else None
    try:
        q = manager.Queue() if manager is not None else None

        def drain() -> None:
            while q is not None:
                try:
                    msg = q.get_nowait()
                except queue_mod.Empty:
                    return
                on_report(msg)  # type: ignore[misc]

        with ctx.Pool(processes, initializer=_pool_init, initargs=(token, setup, q)) as pool:
            results = pool.imap_unordered(_pool_task, [(fn, token, i, item) for i, item in enumerate(items)],
                                          chunksize=1)
            left = len(items)
            while left:
                try:
                    index, value = results.next(timeout=0.2 if q is not None else None)
                except mp.TimeoutError:
                    drain()
                    continue
                drain()
                left -= 1
                yield index, value
    finally:
        if manager is not None:
            manager.shutdown()


def _map_ray(fn: Callable[..., Any], items: list[Any], setup: Callable[[], Any] | None,
             on_report: Callable[[Any], None] | None, token: str, max_retries: int) -> Iterator[tuple[int, Any]]:
    import ray
    from ray.exceptions import RayTaskError

    q = None
    if on_report is not None:
        from ray.util.queue import Queue

        q = Queue(actor_options={"num_cpus": 0})
    task = ray.remote(_ray_task).options(num_cpus=1, max_retries=max_retries, retry_exceptions=False)
    fn_ref, setup_ref = ray.put(fn), ray.put(setup)
    kill_dir = os.environ.get(KILL_FIRST_TRY_ENV) or None
    index = {task.remote(fn_ref, setup_ref, token, item, q, kill_dir): i for i, item in enumerate(items)}
    pending = list(index)

    def drain() -> None:
        if q is not None:
            while not q.empty():
                for msg in q.get_nowait_batch(q.qsize()):
                    on_report(msg)  # type: ignore[misc]

    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1, timeout=0.2 if q is not None else None)
            if done and pending:
                more, pending = ray.wait(pending, num_returns=len(pending), timeout=0)
                done += more
            drain()
            for ref in done:
                try:
                    value = ray.get(ref)
                except RayTaskError as exc:
                    cause = getattr(exc, "cause", None)
                    if isinstance(cause, Exception):
                        raise cause from None
                    raise
                yield index.pop(ref), value  # drop the reference: Ray frees the object
        drain()
    finally:
        for ref in pending:
            try:
                ray.cancel(ref, force=True)
            except Exception:  # already finished or gone
                pass
        if q is not None:
            try:
                q.shutdown(force=True)
            except Exception:
                pass


def _connect_ray(address: str | None, workers: int) -> bool:
    """Join or start Ray; True when this call did (and the caller must shut it down)."""
    try:
        import ray
    except ImportError:
        raise BrlInputError("--executor ray needs Ray: pip install 'brl[ray]'") from None
    if ray.is_initialized():
        return False
    quiet: dict[str, Any] = {"logging_level": logging.ERROR, "log_to_driver": False}
    if address in (None, "auto"):
        found = _running_cluster(ray)
        if found is not None:
            _check_reachable(found)
            return _init(ray, found, quiet)
        if address == "auto":
            raise BrlInputError("--ray-address auto: no running Ray cluster found (start one with ray start --head)")
        address = "local"
    if address == "local":
        return _init(ray, "local", {**quiet, "num_cpus": workers if workers > 1 else None, "include_dashboard": False})
    if not address.startswith("ray://"):
        _check_reachable(address)
    return _init(ray, address, quiet)


def _init(ray: Any, address: str, options: dict[str, Any]) -> bool:
    try:
        ray.init(address=address, **options)
    except Exception as exc:  # Ray raises ConnectionError, ValueError, RuntimeError, ...
        where = "a local Ray instance" if address == "local" else f"the Ray cluster at {address}"
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise BrlInputError(f"cannot start or join {where}: {first}") from None
    return True


def _running_cluster(ray: Any) -> str | None:
    """host:port of the cluster Ray's address "auto" would join, or None when there is none."""
    try:
        from ray._private.services import canonicalize_bootstrap_address

        return canonicalize_bootstrap_address("auto")
    except ConnectionError:
        return None
    except Exception:  # Ray's internals moved: let ray.init decide
        return "auto"


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """A one-line error when nothing listens at host:port (ray.init would retry for minutes)."""
    if address == "auto":
        return
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit():
        raise BrlInputError(f"--ray-address '{address}' is not HOST:PORT (or auto, local, ray://HOST:PORT)")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise BrlInputError(f"cannot reach the Ray cluster at {address}: {exc.strerror or exc}") from None
