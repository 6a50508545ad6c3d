"""`fpv-station export --ray ADDRESS`: the recordings' jobs as tasks on a Ray cluster.

Each recording is one Ray task running `learn.export.export_recording`, as a worker
process would; at most two tasks per CPU of the cluster are in flight, and the results
come back in the recordings' order, so the dataset is the one a single process writes.
The nodes need fpv-station with the `learn` extra installed, and the recordings and
`--out` on storage every node sees at the same path (the part files go there).
ADDRESS is Ray's: `auto` (the cluster this machine belongs to), `ray://HOST:10001` (a
remote cluster's client port), or `local` (a new instance on this machine).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator
from typing import Any


def ray_results(
    run: Callable[[Any], Any], jobs: Iterable[Any], address: str, ahead_per_cpu: int
) -> Iterator[Any]:
    """`run(job)` for each job as a Ray task, the results in the jobs' order."""
    try:
        import ray
    except ImportError:
        raise ImportError(
            "--ray needs Ray: pip install 'fpv-station[export-ray]' (and the same on the "
            "cluster's nodes)"
        ) from None
    started = not ray.is_initialized()
    if started:
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    pending: deque = deque()
    try:
        task = ray.remote(run)
        ahead = max(1, int(ray.cluster_resources().get("CPU", 1))) * ahead_per_cpu
        todo = iter(jobs)
        for job in todo:
            pending.append(task.remote(job))
            if len(pending) >= ahead:
                break
        while pending:
            result = ray.get(pending.popleft())
            for job in todo:
                pending.append(task.remote(job))
                break
            yield result
    finally:
        for ref in pending:
            ray.cancel(ref)
        if started:
            ray.shutdown()
