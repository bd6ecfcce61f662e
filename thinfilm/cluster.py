"""Running a graph of tasks: in this process, on a local Dask cluster, or on an existing one.

``thinfilm benchmark`` and ``thinfilm generate --sweep`` describe their work as
:class:`Task` objects (a function, its arguments, the tasks it depends on) and hand them to
:func:`run_tasks` with an executor from :func:`executor`:

* ``workers=0``: every task in this process, one after another, in the order given (no Dask);
* ``workers=N`` (the commands' default: the number of cores, :func:`auto_workers`): a local Dask cluster
  (``distributed.LocalCluster``) of N worker processes with one task thread each, so each
  process holds one Mitsuba; each worker's thread budget (Dr.Jit's and OpenEXR's pools, the
  noise threads: :mod:`thinfilm.core.threads`) is set to ``max(1, cores // N)`` so that the
  workers together use no more threads than cores;
* ``scheduler=ADDRESS`` (``tcp://host:port``, or the JSON file of
  ``dask scheduler --scheduler-file``): an existing cluster (``dask scheduler`` and
  ``dask worker``); its workers need ``thinfilm`` importable and the output folder on a
  shared file system. Their threads are left as the workers have them. The address is
  checked first (:func:`scheduler_address`), then the scheduler must answer within
  :data:`CONNECT_TIMEOUT_S` seconds in Dask's protocol (:func:`probe_scheduler`): a peer that
  says nothing or speaks another protocol is refused in one line, never waited on.

Dask comes with the ``cluster`` extra (``pip install 'thinfilm[cluster]'``): without it, a
local cluster or ``--scheduler`` is refused in one line naming the extra
(:func:`thinfilm.core.extras.require_extra`), and the commands' default runs every task in
this process.

Each task function sets the Mitsuba variant it needs itself (workers start with none), and
writes its own output folder; what it returns (a small dict) comes back to the caller. The
result of a task never depends on where it ran: a task is a pure function of its arguments.
"""

from __future__ import annotations

import contextlib
import sys
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from thinfilm.core import signals
from thinfilm.core.errors import UserError
from thinfilm.core.extras import has_module, require_extra

__all__ = ["Dep", "Task", "Executor", "default_workers", "auto_workers", "executor", "run_tasks",
           "generate_task"]


@dataclass(frozen=True)
class Dep:
    """Stands for the result of the task named ``key`` among another task's arguments."""

    key: str


@dataclass
class Task:
    """``function(*args)``, where any :class:`Dep` argument is replaced by that task's result."""

    key: str
    function: object
    args: tuple = ()
    label: str = field(default="", compare=False)


def default_workers() -> int:
    """The number of cores this process may use (one worker per core)."""
    from thinfilm.core.threads import cores

    return cores()


def auto_workers() -> int:
    """The workers of a command given neither ``--workers`` nor ``--scheduler``: one per core
    (:func:`default_workers`) on a local Dask cluster, or 0 (every task in this process) when
    the ``cluster`` extra is not installed: a bare installation runs the same tasks, one
    after another (with a :class:`~thinfilm.core.errors.ThinfilmWarning` saying so)."""
    if has_module("distributed"):
        return default_workers()
    import warnings

    from thinfilm.core.errors import ThinfilmWarning
    from thinfilm.core.extras import missing_extra_message

    warnings.warn(f"every task runs in this process: a local Dask cluster {missing_extra_message('cluster')}",
                  ThinfilmWarning, stacklevel=2)
    return 0


def _in_worker(function, drjit_threads, *args):
    """Run ``function(*args)`` on a worker, with its thread budget (Dr.Jit's and OpenEXR's
    pools, the noise threads) set to its share of the cores first."""
    if drjit_threads:
        from thinfilm.core.threads import set_thread_budget

        set_thread_budget(drjit_threads)
    return function(*args)


@dataclass
class Executor:
    """Where tasks run: ``client`` is a ``distributed.Client``, or None for this process."""

    client: object = None
    workers: int = 0
    address: str | None = None
    drjit_threads: int | None = None

    def describe(self) -> dict:
        if self.client is None:
            return {"mode": "in-process", "workers": 0}
        if self.address is not None:
            return {"mode": "scheduler", "workers": self.workers}
        return {"mode": "local-cluster", "workers": self.workers, "drjit_threads": self.drjit_threads}


@contextlib.contextmanager
def executor(workers: int | None = None, scheduler: str | None = None, max_workers: int | None = None,
             worker_threads: int | None = None):
    """Yield an :class:`Executor` (see the module docstring); the local cluster, or the
    connection, is closed on exit.

    ``max_workers`` caps a local cluster (no point starting more workers than tasks);
    ``worker_threads`` sets the Dr.Jit and OpenEXR threads of each of its workers (default
    ``max(1, cores // workers)``)."""
    if scheduler is not None:
        Client = require_extra("distributed", "cluster", argument="scheduler").Client
        address = scheduler_address(scheduler)
        probe_scheduler(address, scheduler)
        try:
            client = Client(address, timeout=f"{CONNECT_TIMEOUT_S:g}s")
        except (OSError, TimeoutError) as e:
            raise UserError(f"--scheduler {scheduler}: cannot connect ({e})") from None
        except (MemoryError, ValueError, TypeError, AssertionError) as e:
            # what a peer that is no Dask scheduler makes the client read (a length out of an
            # HTTP header)
            raise UserError(f"--scheduler {scheduler}: {address} is not a Dask scheduler "
                            f"({type(e).__name__})") from None
        try:
            try:
                client.wait_for_workers(1, timeout=60)
            except TimeoutError:
                raise UserError(f"--scheduler {scheduler}: no worker joined the cluster within 60 s "
                                f"(start some with 'dask worker ADDRESS')") from None
            n = len(client.scheduler_info(n_workers=-1).get("workers", {}))
            yield Executor(client, n, scheduler)
        finally:
            client.close()
        return
    n = default_workers() if workers is None else int(workers)
    if n < 0:
        raise UserError(f"--workers: expected a number >= 0, got {n}")
    if n == 0:
        yield Executor()
        return
    if max_workers is not None:
        n = max(1, min(n, int(max_workers)))
    import logging

    distributed = require_extra("distributed", "cluster", argument="workers")
    Client, LocalCluster = distributed.Client, distributed.LocalCluster

    threads = max(1, default_workers() // n) if worker_threads is None else max(1, int(worker_threads))
    # The cluster is started and closed whole, a signal meanwhile deferred to the end of the
    # step: a cluster half started or half closed would leave its worker processes and the
    # semaphores of their queues behind.
    cluster = client = None
    try:
        with signals.deferred():
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                                   host="127.0.0.1", silence_logs=logging.ERROR)
            client = Client(cluster)
        yield Executor(client, n, None, threads)
    finally:
        with signals.deferred():
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()


#: seconds the connection to ``--scheduler`` may take, including the scheduler's first answer
CONNECT_TIMEOUT_S = 20.0

_SCHEMES = ("tcp", "tls")


def scheduler_address(scheduler: str) -> str:
    """The address of ``--scheduler`` (``tcp://HOST:PORT``, ``tls://HOST:PORT``, or the JSON file
    of ``dask scheduler --scheduler-file`` holding one as ``address``), checked; a malformed one
    is a one-line :class:`UserError` naming the value."""
    import os

    from thinfilm.core.files import read_json

    text = str(scheduler).strip()
    where = f"--scheduler {scheduler}"
    if "://" not in text and (text.lower().endswith(".json") or os.path.exists(os.path.expanduser(text))):
        path = Path(text).expanduser()
        data = read_json(path, missing="a scheduler file written by 'dask scheduler --scheduler-file'")
        address = data.get("address") if isinstance(data, dict) else None
        if not isinstance(address, str):
            raise UserError(f"{path}: 'address' must be a scheduler address (tcp://HOST:PORT), got "
                            f"{address!r}"[:300])
        text, where = address.strip(), f"{path}: 'address' {address}"
    scheme, sep, rest = text.partition("://")
    if not sep:
        raise UserError(f"{where}: expected tcp://HOST:PORT or a scheduler file")
    if scheme.lower() not in _SCHEMES:
        raise UserError(f"{where}: unknown scheme {scheme!r}; expected {' or '.join(s + '://' for s in _SCHEMES)}"
                        f"HOST:PORT")
    host, colon, port = rest.rpartition(":")
    if not colon or not host or "/" in port:
        raise UserError(f"{where}: no port; expected {scheme}://HOST:PORT")
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise UserError(f"{where}: the port must be a number from 1 to 65535, got {port!r}")
    return f"{scheme.lower()}://{host}:{int(port)}"


def probe_scheduler(address: str, scheduler: str, timeout: float | None = None) -> None:
    """Connect to a ``tcp://`` scheduler and read the start of its greeting (a Dask scheduler
    speaks first: a count of frames), all within ``timeout`` (default
    :data:`CONNECT_TIMEOUT_S`): nothing listening, no answer, or an answer in another protocol
    (an HTTP server) is a one-line :class:`UserError`, never a wait without end."""
    import socket
    import struct
    import time

    if not address.startswith("tcp://"):
        return
    timeout = CONNECT_TIMEOUT_S if timeout is None else timeout
    host, _, port = address[len("tcp://"):].rpartition(":")
    host = host.strip("[]")
    end = time.monotonic() + timeout
    try:
        with socket.create_connection((host, int(port)), timeout=timeout) as conn:
            head = b""
            while len(head) < 8:
                conn.settimeout(max(end - time.monotonic(), 0.01))
                block = conn.recv(8 - len(head))
                if not block:
                    raise UserError(f"--scheduler {scheduler}: {address} closed the connection without a "
                                    f"word; not a Dask scheduler")
                head += block
    except socket.timeout:
        raise UserError(f"--scheduler {scheduler}: no answer from {address} within {timeout:g} s "
                        f"(is it a Dask scheduler?)") from None
    except socket.gaierror as e:
        raise UserError(f"--scheduler {scheduler}: cannot connect (unknown host {host!r}: {e.strerror})") from None
    except OSError as e:
        raise UserError(f"--scheduler {scheduler}: cannot connect ({e.strerror or e})") from None
    frames = struct.unpack("<Q", head)[0]
    if not 0 < frames <= 1024:
        raise UserError(f"--scheduler {scheduler}: {address} answered in another protocol "
                        f"({head!r}…); not a Dask scheduler")


def _call(task: Task, results: dict):
    args = tuple(results[a.key] if isinstance(a, Dep) else a for a in task.args)
    return task.function(*args)


def run_tasks(tasks, ex: Executor, on_result=None, progress: bool = False, desc: str = "tasks") -> dict:
    """Run ``tasks`` (dependencies first in the list) on ``ex``; return ``{key: result}``.

    ``on_result(task, result)`` is called as each task finishes (in completion order). A task
    whose function raised, or whose worker died, gets ``{"status": "failed", "error": ...}``
    (task functions normally catch their own errors and say so in their result).
    """
    from tqdm import tqdm

    tasks = list(tasks)
    results: dict = {}
    bar = tqdm(total=len(tasks), desc=desc, unit="task", disable=not progress, file=sys.stderr)
    try:
        if ex.client is None:
            import mitsuba as mi

            previous = mi.variant()
            try:
                for task in tasks:
                    bar.set_postfix_str(task.label or task.key)
                    try:
                        results[task.key] = _call(task, results)
                    except (KeyboardInterrupt, UserError):
                        raise
                    except Exception as e:
                        signals.check_received()  # a signal turned into another error by a library
                        results[task.key] = _failure(e)
                    if on_result is not None:
                        on_result(task, results[task.key])
                    bar.update(1)
            finally:
                if previous is not None and mi.variant() != previous:
                    mi.set_variant(previous)
            return results

        from distributed import as_completed

        token = uuid.uuid4().hex[:10]
        futures, by_future = {}, {}
        for task in tasks:
            args = tuple(futures[a.key] if isinstance(a, Dep) else a for a in task.args)
            fut = ex.client.submit(_in_worker, task.function, ex.drjit_threads, *args,
                                   key=f"{task.key}-{token}", pure=False)
            futures[task.key] = fut
            by_future[fut.key] = task
        for fut in as_completed(list(futures.values())):
            task = by_future[fut.key]
            try:
                results[task.key] = fut.result()
            except KeyboardInterrupt:
                raise
            except Exception as e:
                signals.check_received()
                results[task.key] = _failure(e)
            if on_result is not None:
                on_result(task, results[task.key])
            bar.set_postfix_str(task.label or task.key)
            bar.update(1)
        return results
    finally:
        bar.close()


def generate_task(spec, folder: str) -> dict:
    """The task that generates one dataset: ``spec`` (a
    :class:`~thinfilm.generators.spec.SceneSpec`) into ``folder`` (written atomically; a
    :func:`~thinfilm.core.outputs.staging_path` that the caller adopts into its output).
    Returns ``{"status": "ok", "generate_s": ..., "staged": folder}`` or the failure."""
    import time

    from thinfilm.core.variants import use_variant
    from thinfilm.generators.generate import generate_dataset

    t0 = time.perf_counter()
    try:
        use_variant()
        generate_dataset(spec, folder, progress=False)
    except Exception as e:
        signals.check_received()  # in this process, a signal that a library turned into an error
        return _failure(e)
    return {"status": "ok", "generate_s": round(time.perf_counter() - t0, 2), "staged": folder}


def _failure(e: BaseException) -> dict:
    import traceback

    return {"status": "failed", "error": f"{type(e).__name__}: {e}".splitlines()[0],
            "traceback": "".join(traceback.format_exception(type(e), e, e.__traceback__, limit=6))}
