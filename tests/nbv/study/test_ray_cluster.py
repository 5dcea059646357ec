"""The Ray executor on a local multi-node cluster: two nodes of ``ray.cluster_utils.Cluster`` with one CPU each, on
this machine's loopback address. Jobs spread over both nodes, a worker killed in the middle of a job has the job
run again (or, with no retries left, the error names the job), and the results equal the local executor's.

The jobs are tiny (under half a second each); the module takes about 45-50 s on the shared 2-core machine under
load: 11 s to start the two nodes, most of the rest for the first worker of each node to import nbv (Taichi, torch)
and for the local executor's two processes to start. Skipped, saying why, where Ray is not installed
(``pip install -e .[ray]``).
"""

import importlib.util
import os
import signal
import sys
import threading
import time

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None, reason="Ray is not installed (optional extra: pip install -e .[ray])"
)
NODES = 2
# Ray and the executors are imported inside the functions: the local executor's worker processes import this
# module to find the job function, and importing Ray or nbv (Taichi, torch) there costs seconds for nothing.


def _value(job) -> float:
    """The job's result: deterministic, the same bits in any process."""
    return float(np.random.default_rng(job["seed"]).standard_normal(1000).sum())


def _on_node(job) -> dict:
    """Runs in a Ray worker: the value, after a short wait (so the tasks overlap), with where it ran."""
    import ray

    time.sleep(job.get("sleep", 0.0))
    return {"value": _value(job), "node": ray.get_runtime_context().get_node_id(), "pid": os.getpid()}


def _victim(job) -> dict:
    """The first try writes its process id and waits to be killed; a later try (the file exists) just runs."""
    pid_file = job["pid_file"]
    if not os.path.exists(pid_file):
        with open(pid_file + ".tmp", "w") as fh:
            fh.write(str(os.getpid()))
        os.replace(pid_file + ".tmp", pid_file)
        time.sleep(60.0)  # killed long before this ends
    return _on_node(job)


def _kill_when_written(pid_file: str, killed: list, timeout: float = 60.0) -> threading.Thread:
    """A thread that SIGKILLs the process whose id appears in ``pid_file`` (the victim's Ray worker)."""

    def watch() -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if os.path.exists(pid_file):
                pid = int(open(pid_file).read())
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return
            time.sleep(0.05)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


@pytest.fixture(scope="module")
def cluster():
    """Two Ray nodes (head + one worker node), 1 CPU each, all on 127.0.0.1, and the driver connected to them:
    yields (the cluster's address, the ids of its nodes)."""
    import ray
    from ray.cluster_utils import Cluster

    with pytest.MonkeyPatch.context() as mp:
        # Ray binds to the machine's outward address unless told it is a single-machine cluster: keep every
        # node, worker and connection on the loopback interface (the driver reads the constant, the nodes the
        # environment).
        mp.setenv("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
        mp.setattr(ray._private.ray_constants, "ENABLE_RAY_CLUSTER", False)
        if ray.is_initialized():
            ray.shutdown()
        t0 = time.perf_counter()
        nodes = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
        try:
            for _ in range(NODES - 1):
                nodes.add_node(num_cpus=1)
            nodes.wait_for_nodes()
            ray.init(address=nodes.address, include_dashboard=False)
            # the workers unpickle this module's job functions by value (tests/ is no package they can import)
            ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
            alive = {n["NodeID"] for n in ray.nodes() if n["Alive"]}
            assert len(alive) == NODES and ray.cluster_resources().get("CPU") == NODES
            print(f"{NODES}-node Ray cluster up in {time.perf_counter() - t0:.1f} s")
            yield nodes.address, alive
        finally:
            ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
            ray.shutdown()
            nodes.shutdown()


def test_jobs_spread_over_both_nodes_and_equal_the_local_executor(cluster):
    from nbv.study.executors import LocalExecutor, RayExecutor

    address, nodes = cluster
    jobs = [{"seed": s, "sleep": 0.4} for s in range(6)]
    ray_results = {job["seed"]: r for job, r in RayExecutor(address=address).map(_on_node, jobs)}
    assert sorted(ray_results) == list(range(6))
    assert {r["node"] for r in ray_results.values()} == nodes  # every node ran some of them
    local = {job["seed"]: r for job, r in LocalExecutor(workers=2).map(_value, jobs)}
    assert {s: r["value"] for s, r in ray_results.items()} == local  # the same bits


def test_a_killed_worker_has_its_job_run_again(cluster, tmp_path):
    from nbv.study.executors import RayExecutor

    pid_file = str(tmp_path / "victim.pid")
    jobs = [{"seed": 7, "pid_file": pid_file}, {"seed": 8, "pid_file": pid_file + ".unused", "sleep": 0.2}]
    killed: list[int] = []
    watcher = _kill_when_written(pid_file, killed)
    executor = RayExecutor(address=cluster[0], max_retries=2)
    results = {job["seed"]: r for job, r in executor.map(_victim_or_value, jobs)}
    watcher.join(timeout=5.0)
    assert len(killed) == 1  # the first try was killed mid-job ...
    assert results[7]["pid"] != killed[0]  # ... and another worker ran it again
    assert results[7]["value"] == _value(jobs[0]) and results[8]["value"] == _value(jobs[1])


def _victim_or_value(job) -> dict:
    return _victim(job) if job["seed"] == 7 else _on_node(job)


def test_a_job_whose_worker_dies_on_every_try_is_reported_by_name(cluster, tmp_path):
    from nbv.study.executors import JobLost, RayExecutor

    pid_file = str(tmp_path / "victim.pid")
    job = {"seed": 7, "pid_file": pid_file, "name": "the victim"}
    killed: list[int] = []
    watcher = _kill_when_written(pid_file, killed)
    with pytest.raises(JobLost, match="the victim.*worker died on 1 try .*raise max_retries") as info:
        list(RayExecutor(address=cluster[0], max_retries=0).map(_victim, [job]))
    watcher.join(timeout=5.0)
    assert len(killed) == 1 and info.value.job == job
    with pytest.raises(ValueError, match="max_retries"):
        RayExecutor(max_retries=-1)
