"""A real two-node Ray cluster on this machine, started as docs/compare.md says (token
authentication: RAY_AUTH_MODE=token and the token in ~/.ray/auth_token on each node):
``sweep --backend ray --address`` completes with the local backend's numbers although
the second node's raylet is SIGKILLed mid-sweep, and without the token mode the
command is one line saying what to do.

Everything runs in a temporary HOME and Ray temp dir, on free ports, each node a
``ray start --block`` in its own process group; the test stops only those groups (and
any process left that names its temp dir), never another user's Ray.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("ray")

BIN = Path(sys.executable).parent
CLI = [sys.executable, "-m", "observer_gym.train.cli"]
SWEEP = [
    "sweep", "--vary", "measurement_noise_px=0,2", "--observers", "oracle,kf-measurements",
    "--controllers", "lqr", "--episodes", "10", "--steps", "100", "--no-progress",
]  # fmt: skip


def _free_ports(n: int) -> list[int]:
    sockets = [socket.socket() for _ in range(n)]
    for s in sockets:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in sockets]
    for s in sockets:
        s.close()
    return ports


def _node(env: dict[str, str], temp_dir: Path, log: Path, *args: str) -> subprocess.Popen:
    """``ray start ... --block`` with one CPU on 127.0.0.1, its own ports and temp dir."""
    ports = _free_ports(6)
    command = [
        str(BIN / "ray"), "start", *args, "--num-cpus", "1", "--node-ip-address", "127.0.0.1",
        "--temp-dir", str(temp_dir), "--object-store-memory", str(200 * 2**20),
        "--object-manager-port", str(ports[0]), "--node-manager-port", str(ports[1]),
        "--dashboard-agent-listen-port", str(ports[2]),
        "--dashboard-agent-grpc-port", str(ports[3]), "--runtime-env-agent-port", str(ports[4]),
        "--metrics-export-port", str(ports[5]), "--disable-usage-stats", "--block",
    ]  # fmt: skip
    return subprocess.Popen(
        command, env=env, stdout=log.open("w"), stderr=subprocess.STDOUT, start_new_session=True
    )


def _group(pgid: int) -> list[tuple[int, str]]:
    """(pid, command line) of the processes in process group ``pgid``."""
    found = []
    for proc in Path("/proc").iterdir():
        try:
            stat = (proc / "stat").read_text()
            if proc.name.isdigit() and int(stat[stat.rfind(")") + 2 :].split()[2]) == pgid:
                found.append((int(proc.name), (proc / "cmdline").read_bytes().decode()))
        except (OSError, ValueError, IndexError):
            continue
    return found


def _stop(nodes: list[subprocess.Popen], temp_dir: Path) -> None:
    """SIGTERM the nodes' process groups, SIGKILL what is left of them after 15 s, and
    any process naming ``temp_dir`` (a Ray worker outside the groups)."""
    for node in nodes:
        try:
            os.killpg(node.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline and any(_group(n.pid) for n in nodes):
        time.sleep(0.5)
    for node in nodes:
        try:
            os.killpg(node.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        node.wait(timeout=30)
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and str(temp_dir) in (proc / "cmdline").read_bytes().decode():
                os.kill(int(proc.name), signal.SIGKILL)
        except (OSError, ValueError):
            continue


@pytest.fixture
def cluster(tmp_path) -> Iterator[tuple[str, dict[str, str], subprocess.Popen]]:
    """(address, the environment of its nodes and drivers, the second node)."""
    home = tmp_path / "home"
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    env.update(HOME=str(home), RAY_AUTH_MODE="token")
    subprocess.run(
        [str(BIN / "ray"), "get-auth-token", "--generate"], env=env, check=True, capture_output=True
    )  # the head's token; on real nodes, copied to each node's ~/.ray/auth_token
    temp_dir = Path(f"/tmp/og-ray-{os.getpid()}-{time.monotonic_ns()}")  # a socket path < 108 B
    (gcs_port,) = _free_ports(1)
    address = f"127.0.0.1:{gcs_port}"
    nodes = []
    try:
        head = ["--head", "--port", str(gcs_port), "--include-dashboard", "false"]
        nodes.append(_node(env, temp_dir, tmp_path / "head.log", *head))
        _wait_for_cpus(address, env, 1, nodes[0], tmp_path / "head.log")
        nodes.append(_node(env, temp_dir, tmp_path / "node.log", "--address", address))
        _wait_for_cpus(address, env, 2, nodes[1], tmp_path / "node.log")
        yield address, env, nodes[1]
    finally:
        _stop(nodes, temp_dir)
        subprocess.run(["rm", "-rf", str(temp_dir)], check=False)


def _wait_for_cpus(address: str, env: dict, cpus: int, node: subprocess.Popen, log: Path) -> None:
    deadline = time.monotonic() + 120
    while True:
        assert node.poll() is None, log.read_text()[-3000:]
        status = subprocess.run(
            [str(BIN / "ray"), "status", "--address", address], env=env, capture_output=True,
            text=True, timeout=60,
        )  # fmt: skip
        if f"/{float(cpus)} CPU" in status.stdout:
            return
        assert time.monotonic() < deadline, status.stdout + status.stderr
        time.sleep(1)


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow  # two Ray nodes, a sweep on them and one local: about a minute
def test_a_sweep_on_a_two_node_cluster_survives_a_killed_raylet(cluster, tmp_path):
    address, env, second = cluster
    out = tmp_path / "ray"
    sweep = subprocess.Popen(
        [*CLI, *SWEEP, "--backend", "ray", "--address", address, "--out", str(out)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 300
        while not list((out / "cells").glob("*.json")):  # a quarter of the episodes in
            assert sweep.poll() is None, sweep.stdout.read().decode()
            assert time.monotonic() < deadline, "no cell within 300 s"
            time.sleep(0.2)
        (raylet,) = [p for p, cmd in _group(second.pid) if cmd.split("\0")[0].endswith("/raylet")]
        os.kill(raylet, signal.SIGKILL)
        output, _ = sweep.communicate(timeout=600)
    finally:
        sweep.kill()
    assert sweep.returncode == 0, output.decode()
    assert len(list((out / "cells").glob("*.json"))) == 4

    local = tmp_path / "local"
    subprocess.run([*CLI, *SWEEP, "--workers", "2", "--out", str(local)], env=env, check=True)
    assert _rows(out / "episodes.csv") == _rows(local / "episodes.csv")  # 40 episodes
    assert len(_rows(out / "episodes.csv")) == 40
    for name in ("episodes.csv", "table.md"):
        assert (out / name).read_bytes() == (local / name).read_bytes()
    ray_results, local_results = (
        json.loads((d / "results.json").read_text()) for d in (out, local)
    )
    assert ray_results["cells"] == local_results["cells"]


@pytest.mark.slow
def test_without_token_mode_the_address_is_one_line_saying_what_to_do(cluster, tmp_path):
    address, env, _ = cluster
    env = {k: v for k, v in env.items() if k != "RAY_AUTH_MODE"}  # the token file is there
    done = subprocess.run(
        [*CLI, *SWEEP, "--backend", "ray", "--address", address, "--out", str(tmp_path / "x")],
        env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 1
    assert done.stderr.splitlines() == [done.stderr.strip()]
    line = done.stderr.strip()
    assert line.startswith(
        f"observer-gym sweep: error: could not connect to the Ray cluster at {address}"
    )
    assert "RAY_AUTH_MODE=token" in line
