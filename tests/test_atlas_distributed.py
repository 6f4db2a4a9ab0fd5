"""The atlas on a real Dask cluster: a scheduler and worker processes started here with the
``dask`` command line on 127.0.0.1 (no mocks), the atlas run through ``--scheduler``, a worker
killed mid-run, an interrupted run. Every process started is stopped in the fixtures' finally."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from atlas_cases import SETUP, robot_file, same_table
from robot_helpers import REPO, shared_dir

DASK = str(Path(sys.executable).with_name("dask"))
BOX = ["1.5", "-0.6", "0.4", "2.4", "0.6", "0.7"]


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env["ROBOMILL_SHARED"] = str(shared_dir())
    env.update({"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"})
    return env


class _Cluster:
    def __init__(self, directory: Path):
        self.dir = directory
        self.procs: dict[str, subprocess.Popen] = {}
        self.address = None

    def spawn(self, name: str, args: list[str]) -> subprocess.Popen:
        log = open(self.dir / f"{name}.log", "wb")
        proc = subprocess.Popen([DASK, *args], env=_env(), stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, cwd=self.dir)
        log.close()
        self.procs[name] = proc
        return proc

    def start_scheduler(self):
        sched = self.dir / "scheduler.json"
        self.spawn("scheduler", ["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                 "--scheduler-file", str(sched)])
        deadline = time.monotonic() + 60
        while not sched.exists() or not sched.read_text().strip():
            if time.monotonic() > deadline or self.procs["scheduler"].poll() is not None:
                raise RuntimeError("the dask scheduler did not start: " + (self.dir / "scheduler.log").read_text())
            time.sleep(0.1)
        time.sleep(0.1)  # the file is written in one go; let it be flushed
        self.address = json.loads(sched.read_text())["address"]
        assert self.address.startswith("tcp://127.0.0.1:")

    def start_worker(self, name: str):
        self.spawn(name, ["worker", self.address, "--name", name, "--nthreads", "1", "--no-nanny",
                          "--no-dashboard", "--host", "127.0.0.1", "--memory-limit", "0"])

    def wait_for_workers(self, names):
        from distributed import Client

        with Client(self.address, timeout="30s", set_as_default=False) as client:
            deadline = time.monotonic() + 90
            while True:
                present = {w["name"] for w in client.scheduler_info(n_workers=-1)["workers"].values()}
                if set(names) <= present:
                    return
                dead = [n for n in names if self.procs[n].poll() is not None]
                if dead or time.monotonic() > deadline:
                    raise RuntimeError(f"dask workers {names} did not register: "
                                       + (self.dir / f"{names[-1]}.log").read_text()[-2000:])
                time.sleep(0.2)

    def stop(self):
        """SIGKILL to every process still running (they hold no state worth a graceful exit), reaped."""
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.kill()
        for proc in self.procs.values():
            proc.wait(timeout=30)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    c = _Cluster(tmp_path_factory.mktemp("dask"))
    try:
        c.start_scheduler()
        c.start_worker("w0")
        c.start_worker("w1")
        c.wait_for_workers(["w0", "w1"])
        yield c
    finally:
        c.stop()


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    return robot_file(tmp_path_factory.mktemp("atlas_robot"))


def _atlas(robot, out, *extra):
    from planner.cli import main

    return main(["atlas", str(robot), str(SETUP), "-o", str(out), "--box-m", *BOX, "--step-m", "0.3",
                 "--rotations-deg", "-90", "0", "90", "--json", "--no-progress", *extra])


def test_distributed_run_equals_serial(cluster, robot, tmp_path, capsys):
    from planner.atlas.io import read_table

    assert _atlas(robot, tmp_path / "serial", "--scheduler", "serial", "--no-plots") == 0
    serial = json.loads(capsys.readouterr().out)
    assert _atlas(robot, tmp_path / "dask", "--scheduler", cluster.address, "--chunk-points", "3", "--no-plots") == 0
    dist = json.loads(capsys.readouterr().out)
    assert dist["engine"]["chunks"] > 4  # several tasks, shared by the two workers
    a, meta = read_table(serial["table"])
    b, _ = read_table(dist["table"])
    assert same_table(a, b)  # bit for bit
    assert dist["best"] == serial["best"] and dist["points"] == serial["points"] == 40
    assert meta["format"] == "robomill-atlas/1"
    assert dist["figures"] == {}  # figures: test_atlas_cli.py::test_demo_section
    assert "x_m" in a and "mrr_m3_s" in a and "depth_limit_m" in a  # units in the column names


def test_interrupted_run_leaves_no_table(cluster, robot, tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "planner.cli", "atlas", str(robot), str(SETUP), "-o", str(out), "--box-m", *BOX,
           "--step-m", "0.05", "--scheduler", cluster.address, "--chunk-points", "10"]
    # a pytest-xdist worker may run with SIGINT ignored, and an ignored signal stays ignored across
    # exec (Python then installs no KeyboardInterrupt handler): give the child the default, as a
    # terminal would
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        buf = b""
        deadline = time.monotonic() + 60
        while b"chunk" not in buf:  # the progress bar has started: the cluster is computing
            assert time.monotonic() < deadline and proc.poll() is None, buf.decode(errors="replace")
            buf += os.read(proc.stderr.fileno(), 256)
        time.sleep(1.0)
        # Ctrl-C as a user gives it: again if the run goes on (twice in the full suite the first
        # one was lost while the run continued to the end; not reproduced alone)
        err = b""
        for _ in range(5):
            proc.send_signal(signal.SIGINT)
            try:
                _, err = proc.communicate(timeout=2.0)
                break
            except subprocess.TimeoutExpired:
                continue
        else:
            _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 3, err.decode(errors="replace")
    assert "interrupted" in err.decode()
    assert not out.exists() or not any(out.iterdir())  # no table, no temporary file
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]


def test_unreachable_scheduler_exits_2_quickly(robot, tmp_path, capsys):
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.monotonic()
    assert _atlas(robot, tmp_path / "out", "--scheduler", f"tcp://127.0.0.1:{port}", "--connect-timeout-s", "2") == 2
    err = capsys.readouterr().err
    assert time.monotonic() - t0 < 15
    assert err.count("\n") == 1 and "--scheduler" in err and f"127.0.0.1:{port}" in err
    assert not (tmp_path / "out").exists()


def test_killed_worker_is_recovered_from(cluster, robot, tmp_path):
    """Worker w1 is killed (SIGKILL of its process) while it holds tasks; its chunks are recomputed
    by w0 and the table equals the serial one. (Last in this module: it leaves one worker.)"""
    from distributed import Client

    from planner.atlas import Region, build_problem, run_atlas
    from planner.robot import read_robot
    from stability.setup_io import read_setup

    problem_robot = read_robot(robot)
    region = Region([1.5, -0.6, 0.3], [2.4, 0.6, 0.9], 0.1, [-90.0, 0.0, 90.0])
    problem = build_problem(problem_robot, read_setup(SETUP), region)
    reference = run_atlas(problem, region, scheduler="serial", progress=False, points_per_chunk=50)
    seen = {}
    client = Client(cluster.address, timeout="10s", set_as_default=False)
    try:
        victim = next(a for a, w in client.scheduler_info(n_workers=-1)["workers"].items() if w["name"] == "w1")

        def kill_when_busy(done, total):
            if "killed" in seen:
                return
            busy = client.processing(workers=[victim]).get(victim, ())
            if busy:
                seen["killed"] = len(busy)
                os.kill(cluster.procs["w1"].pid, signal.SIGKILL)

        result = run_atlas(problem, region, scheduler=cluster.address, progress=False, points_per_chunk=20,
                           on_chunk_done=kill_when_busy)
    finally:
        client.close()
    assert seen.get("killed", 0) >= 1, "w1 never held a task: nothing was tested"
    assert cluster.procs["w1"].wait(timeout=10) == -signal.SIGKILL
    assert result.engine["chunks"] >= 20
    assert same_table(reference.columns, result.columns)
    assert result.best == reference.best
