"""A lab of several hosts on one machine: network namespaces joined by a bridge.

:func:`lab_net` builds one namespace per host of :data:`HOSTS` (a mocap host, a module host
with the plant and its valve emulator, an estimator host, a router host), each with its own
network stack: a veth pair from the namespace (``eth0``, address :data:`LAN_ADDR`) to a
bridge in the machine's own namespace (no address there: the lab cannot reach the machine's
network, nor it the lab). The module and mocap hosts also share a point-to-point "camera
link" (``cam0``, :data:`CAMERA_ADDR`): the mocap cameras see the module whatever happens to
the lab network, so a partition of the mocap host cuts its Zenoh traffic, not its poses.

Faults: :meth:`LabNet.link` (``ip link set eth0 down|up`` inside a host),
:meth:`LabNet.loss` (nftables ``numgen random mod 100 < P drop`` on a host's eth0, both
directions). Processes: :meth:`LabNet.spawn` (``ip netns exec``), all killed at the end.

Every name carries a tag made of this process's id and a counter (``tl<pid hex><n>``), so
parallel xdist workers never collide; :func:`clean_leftovers` removes the namespaces and
links of tags whose process is gone (a worker killed before its ``finally``). Everything is
torn down on every exit path (the context manager's ``finally``; :func:`atexit` for the
rest). :func:`refusal` says why this machine cannot build a lab (not root, no ``ip``, the
kernel refusing a namespace), for the tests to skip with that reason.
"""

from __future__ import annotations

import atexit
import contextlib
import itertools
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

HOSTS = ("router", "mocap", "module", "estimator")
LAN_ADDR = {"router": "10.77.0.1", "mocap": "10.77.0.2", "module": "10.77.0.3",
            "estimator": "10.77.0.4", "laptop": "10.77.0.9"}
"""Each host's address on the lab network (/24); the same in every lab: they are private.
("laptop": a stranger on the lab network, for the access tests.)"""
CAMERA_ADDR = {"module": "10.78.0.1", "mocap": "10.78.0.2"}
"""The camera link between the module and the mocap host (/30)."""
ROUTER_PORT = 7447
_TAG = re.compile(r"^tl([0-9a-f]+)x([0-9a-f]+)")
_counter = itertools.count()
_open: set[LabNet] = set()


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check, timeout=20)


def refusal() -> str | None:
    """Why a lab of namespaces cannot be built here (None: it can)."""
    if shutil.which("ip") is None:
        return "the `ip` command (iproute2) is not installed"
    if os.geteuid() != 0:
        return "network namespaces need root (run the tests as root, as CI does)"
    name = f"tlprobe{os.getpid():x}"
    p = _ip("netns", "add", name, check=False)
    if p.returncode != 0:
        return f"the kernel refuses a network namespace (`ip netns add`: {p.stderr.strip()})"
    _ip("netns", "del", name, check=False)
    return None


def nft_refusal() -> str | None:
    """Why nftables cannot drop packets here (None: it can)."""
    if shutil.which("nft") is None:
        return "`nft` is not installed (Debian package nftables; `make setup` installs it as root)"
    return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_leftovers() -> list[str]:
    """Delete the namespaces and links of labs whose process is gone; their names."""
    gone: list[str] = []
    ns = _ip("netns", "list", check=False).stdout.split("\n")
    links = _ip("-o", "link", "show", check=False).stdout.split("\n")
    names = [line.split()[0] for line in ns if line.strip()]
    names += [line.split(":")[1].strip().split("@")[0] for line in links if line.count(":") >= 2]
    for name in names:
        m = _TAG.match(name)
        if m is None or _alive(int(m.group(1), 16)):
            continue
        kind = "netns" if name in (line.split()[0] for line in ns if line.strip()) else "link"
        _ip(*(("netns", "del", name) if kind == "netns" else ("link", "del", name)), check=False)
        gone.append(name)
    return gone


class LabNet:
    """The namespaces of one lab (see the module notes). Use :func:`lab_net`."""

    def __init__(self, hosts: Sequence[str] = HOSTS) -> None:
        self.tag = f"tl{os.getpid():x}x{next(_counter):x}"
        self.hosts = tuple(hosts)
        self.bridge = f"{self.tag}br"
        self.procs: list[subprocess.Popen] = []
        self._made_ns: list[str] = []
        self._made_links: list[str] = []
        self.events: list[tuple[float, str]] = []
        """(host time.time(), what) of every fault made, for the tests' reports."""

    # ------------------------------------------------------------------ naming
    def ns(self, host: str) -> str:
        """The namespace of ``host``."""
        return f"{self.tag}-{host}"

    @staticmethod
    def addr(host: str) -> str:
        return LAN_ADDR[host]

    @property
    def router_ep(self) -> str:
        """The Zenoh endpoint of the router host."""
        return f"tcp/{LAN_ADDR['router']}:{ROUTER_PORT}"

    # ------------------------------------------------------------------ building
    def build(self) -> LabNet:
        _open.add(self)
        _ip("link", "add", self.bridge, "type", "bridge")
        self._made_links.append(self.bridge)
        _ip("link", "set", self.bridge, "up")
        for i, host in enumerate(self.hosts):
            ns = self.ns(host)
            _ip("netns", "add", ns)
            self._made_ns.append(ns)
            self.ip(host, "link", "set", "lo", "up")
            outer = f"{self.tag}h{i}"
            _ip("link", "add", outer, "type", "veth", "peer", "name", f"{self.tag}i{i}")
            self._made_links.append(outer)
            _ip("link", "set", f"{self.tag}i{i}", "netns", ns)
            self.ip(host, "link", "set", f"{self.tag}i{i}", "name", "eth0")
            self.ip(host, "addr", "add", f"{LAN_ADDR[host]}/24", "dev", "eth0")
            self.ip(host, "link", "set", "eth0", "up")
            _ip("link", "set", outer, "master", self.bridge)
            _ip("link", "set", outer, "up")
        if "module" in self.hosts and "mocap" in self.hosts:
            a, b = f"{self.tag}ca", f"{self.tag}cb"
            _ip("link", "add", a, "type", "veth", "peer", "name", b)
            self._made_links.append(a)
            for host, dev in (("module", a), ("mocap", b)):
                _ip("link", "set", dev, "netns", self.ns(host))
                self.ip(host, "link", "set", dev, "name", "cam0")
                self.ip(host, "addr", "add", f"{CAMERA_ADDR[host]}/30", "dev", "cam0")
                self.ip(host, "link", "set", "cam0", "up")
        return self

    def ip(self, host: str, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        """``ip -n NS ARGS`` in ``host``'s namespace."""
        return _ip("-n", self.ns(host), *args, check=check)

    def run(self, host: str, argv: Sequence[str], **kw) -> subprocess.CompletedProcess:
        """Run ``argv`` in ``host``'s namespace to its end."""
        kw.setdefault("capture_output", True)
        kw.setdefault("text", True)
        kw.setdefault("timeout", 60)
        return subprocess.run(["ip", "netns", "exec", self.ns(host), *argv], **kw)

    def spawn(self, host: str, argv: Sequence[str], **kw) -> subprocess.Popen:
        """Start ``argv`` in ``host``'s namespace (its own process group; killed at the
        end of the lab if still running)."""
        kw.setdefault("start_new_session", True)
        p = subprocess.Popen(["ip", "netns", "exec", self.ns(host), *argv], **kw)
        self.procs.append(p)
        return p

    # ------------------------------------------------------------------ faults
    def link(self, host: str, up: bool, dev: str = "eth0") -> None:
        """Take ``host``'s link ``dev`` down or up (``ip link set DEV down|up`` in it)."""
        self.ip(host, "link", "set", dev, "up" if up else "down")
        self.events.append((time.time(), f"{host} {dev} {'up' if up else 'down'}"))

    def partition(self, host: str, seconds: float, dev: str = "eth0") -> threading.Thread:
        """Take ``host``'s link down for ``seconds`` from now (in a thread; returned)."""
        def cut() -> None:
            self.link(host, False, dev)
            time.sleep(seconds)
            self.link(host, True, dev)
        th = threading.Thread(target=cut, name=f"partition-{host}", daemon=True)
        th.start()
        return th

    def loss(self, host: str, percent: int, dev: str = "eth0") -> None:
        """Drop ``percent`` % of the packets in and out of ``host``'s ``dev`` at random
        (nftables ``numgen random mod 100 < P drop``); 0 removes the rule."""
        self.run(host, ["nft", "delete", "table", "inet", "tpodslab"], check=False)
        if percent <= 0:
            self.events.append((time.time(), f"{host} loss off"))
            return
        p = int(percent)
        script = (f"table inet tpodslab {{\n"
                  f" chain in {{\n  type filter hook input priority 0; policy accept;\n"
                  f"  iifname \"{dev}\" numgen random mod 100 < {p} counter drop\n }}\n"
                  f" chain out {{\n  type filter hook output priority 0; policy accept;\n"
                  f"  oifname \"{dev}\" numgen random mod 100 < {p} counter drop\n }}\n}}\n")
        r = self.run(host, ["nft", "-f", "-"], input=script)
        if r.returncode != 0:
            raise RuntimeError(f"nft refused the loss rule: {r.stderr.strip()}")
        self.events.append((time.time(), f"{host} loss {percent} %"))

    def counters(self, host: str) -> str:
        """nftables' ruleset of ``host`` (with counters where set)."""
        return self.run(host, ["nft", "list", "ruleset"]).stdout

    # ------------------------------------------------------------------ teardown
    def stop(self, p: subprocess.Popen, sig: int = signal.SIGTERM, timeout: float = 10.0) -> int:
        """Signal ``p``'s process group, wait ``timeout`` s, then kill it; its exit status."""
        if p.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, sig)
            try:
                p.wait(timeout)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGKILL)
                p.wait(5.0)
        return p.returncode

    def close(self) -> None:
        """Kill what still runs, delete the namespaces and links (idempotent)."""
        for p in self.procs:
            if p.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGKILL)
        for p in self.procs:
            with contextlib.suppress(Exception):
                p.wait(5.0)
        for ns in reversed(self._made_ns):
            _ip("netns", "del", ns, check=False)
        for link in reversed(self._made_links):
            _ip("link", "del", link, check=False)  # gone with its namespace mostly
        self._made_ns.clear()
        self._made_links.clear()
        _open.discard(self)


@contextmanager
def lab_net(hosts: Sequence[str] = HOSTS) -> Iterator[LabNet]:
    """A lab of namespaces (see :class:`LabNet`), torn down on every exit path."""
    clean_leftovers()
    lab = LabNet(hosts)
    try:
        yield lab.build()
    finally:
        lab.close()


@atexit.register
def _close_all() -> None:  # a lab left open by an interrupted run
    for lab in list(_open):
        lab.close()


def python_argv(module: str, *args: str) -> list[str]:
    """``python -m MODULE ARGS`` with this interpreter (the project on PYTHONPATH)."""
    return [sys.executable, "-m", module, *args]


def project_env(**extra: str) -> dict[str, str]:
    """The environment of a lab process: this one's, the project first on PYTHONPATH."""
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env.update(extra)
    return env
