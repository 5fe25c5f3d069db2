"""Vicon DataStream SDK source, with two interchangeable back ends.

* ``vicon_dssdk``: Vicon's own Python package, from the DataStream SDK installer (not on
  PyPI; Vicon documents its Python interface for Windows).
* ``pyvicon``: ``pyvicon-datastream`` from PyPI (``pip install '.[vicon]'``), which
  compiles the SDK's C++ sources on install (Linux, macOS, ARM).

``backend="auto"`` takes whichever imports, ``vicon_dssdk`` first. Both go through the
same code: server-push mode, axis mapping set to the SDK's Z-up default explicitly, and
per frame the frame number, the total latency (s) and for every subject the *root*
segment's global translation (mm) and rotation quaternion with their occlusion flags.

The two APIs differ in shape; the adapters below take care of it:

* failures: vicon_dssdk raises ``DataStreamException``; pyvicon returns a ``Result`` enum
  or None (and raises ValueError for a result code its enum lacks).
* no new frame: ``GetFrame()`` returns False; ``get_frame()`` returns ``Result.NoFrame``.
* translation: ``((x, y, z) mm, occluded)``; ``np.array([x, y, z])`` mm, or None when
  occluded *or* on any failure.
* quaternion: ``((x, y, z, w), occluded)``; ``np.array([w, x, y, z])`` or None.
* subjects: ``GetSubjectNames()``; ``get_subject_count()`` and ``get_subject_name(i)``.
* latency: ``GetLatencyTotal()`` and ``get_latency_total()``, both seconds.

A client object can be injected (tests pass fakes of either API). A frame that cannot
be read is counted (``frame_errors``, ``no_frame``) and skipped; a lost connection is
counted (``disconnects``) and re-established (``reconnects``) without ending the stream.

Read for this: Vicon's ``ViconDataStream.py`` docstrings (a vendored copy:
riccardodelmedico/Crazyflie ``vicon_dssdk/ViconDataStream.py``) and
steffensc/pyvicon-datatstream-module ``pyvicon_datastream/pyvicon_datastream.py``,
``pyvicon_datastream_wrapper.cpp`` and ``tools.py``; what was checked: docs/devices.md.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from common.errors import DeviceError, UserError
from mocap_bridge.pose import PoseSample, occluded_sample

BACKENDS = ("auto", "vicon_dssdk", "pyvicon")
DEFAULT_PORT = 801  # "The function defaults to connecting on port 801" (ViconDataStream.Connect)

INSTALL_HINT = ("on Linux, macOS or ARM run pip install '.[vicon]' (pyvicon-datastream, built from "
                "the SDK sources: needs CMake and a C++ compiler); on Windows install Vicon's "
                "DataStream SDK and its vicon_dssdk Python package; or use --source vicon-udp")


def _notice(msg: str) -> None:
    print(f"vicon-sdk: {msg}", file=sys.stderr, flush=True)


def _result_name(r: Any) -> str:
    """Name of a pyvicon ``Result`` (an Enum); anything else by its text."""
    return str(getattr(r, "name", r))


class _SetupError(Exception):
    pass


class _DSSDK:
    """Adapter over ``vicon_dssdk.ViconDataStream.Client`` (errors raise)."""

    name = "vicon_dssdk"

    def __init__(self, client: Any, server_push: Any, axis_mapping: tuple | None) -> None:
        self.c = client
        self.server_push = server_push
        self.axis_mapping = axis_mapping

    def connect(self, host: str) -> None:
        self.c.Connect(host)

    def is_connected(self) -> bool:
        return bool(self.c.IsConnected())

    def setup(self) -> None:
        self.c.EnableSegmentData()
        if self.server_push is not None:
            self.c.SetStreamMode(self.server_push)
        if self.axis_mapping is not None:
            self.c.SetAxisMapping(*self.axis_mapping)

    def get_frame(self) -> bool:
        # True: a frame; False: NoFrame (the SDK returns False rather than raising).
        # Older SDKs returned None on success: only an explicit False means no frame.
        return self.c.GetFrame() is not False

    def frame_number(self) -> int:
        return int(self.c.GetFrameNumber())

    def latency_s(self) -> float:
        return float(self.c.GetLatencyTotal())

    def subjects(self) -> list[str | None]:
        return list(self.c.GetSubjectNames())

    def root_segment(self, subject: str) -> str | None:
        return self.c.GetSubjectRootSegmentName(subject)

    def translation(self, subject: str, segment: str) -> tuple[Any, bool]:
        p, occ = self.c.GetSegmentGlobalTranslation(subject, segment)
        return p, bool(occ)

    def rotation_xyzw(self, subject: str, segment: str) -> tuple[Any, bool]:
        q, occ = self.c.GetSegmentGlobalRotationQuaternion(subject, segment)  # (x, y, z, w)
        return q, bool(occ)

    def disconnect(self) -> None:
        self.c.Disconnect()


class _PyVicon:
    """Adapter over ``pyvicon_datastream.PyVicon`` (errors come back as Result or None)."""

    name = "pyvicon"

    def __init__(self, client: Any, pv: Any) -> None:
        self.c = client
        self.pv = pv

    def _ok(self, r: Any, what: str, also: tuple[str, ...] = ()) -> None:
        name = _result_name(r)
        if name != "Success" and name not in also:
            raise _SetupError(f"{what}: {name}")

    def connect(self, host: str) -> None:
        self._ok(self.c.connect(host), "connect", also=("ClientAlreadyConnected",))

    def is_connected(self) -> bool:
        return bool(self.c.is_connected())

    def setup(self) -> None:
        pv = self.pv
        self._ok(self.c.enable_segment_data(), "enable_segment_data")
        self._ok(self.c.set_stream_mode(pv.StreamMode.ServerPush), "set_stream_mode")
        self._ok(self.c.set_axis_mapping(pv.Direction.Forward, pv.Direction.Left, pv.Direction.Up),
                 "set_axis_mapping")

    def get_frame(self) -> bool:
        name = _result_name(self.c.get_frame())
        if name == "Success":
            return True
        if name == "NoFrame":
            return False
        raise _SetupError(f"get_frame: {name}")

    def frame_number(self) -> int:
        return int(self.c.get_frame_number())

    def latency_s(self) -> float:
        return float(self.c.get_latency_total())

    def subjects(self) -> list[str | None]:
        n = self.c.get_subject_count()
        return [self.c.get_subject_name(i) for i in range(int(n or 0))]

    def root_segment(self, subject: str) -> str | None:
        return self.c.get_subject_root_segment_name(subject)

    def translation(self, subject: str, segment: str) -> tuple[Any, bool]:
        p = self.c.get_segment_global_translation(subject, segment)
        return (None, True) if p is None else (tuple(p), False)

    def rotation_xyzw(self, subject: str, segment: str) -> tuple[Any, bool]:
        q = self.c.get_segment_global_quaternion(subject, segment)
        if q is None:
            return None, True
        w, x, y, z = q  # pyvicon returns (w, x, y, z); the SDK itself gives (x, y, z, w)
        return (x, y, z, w), False

    def disconnect(self) -> None:
        self.c.disconnect()


def _import_dssdk():
    # lazy: optional SDK binding, imported only when chosen
    from vicon_dssdk import ViconDataStream  # type: ignore[import-not-found]

    return ViconDataStream


def _import_pyvicon():
    # lazy: optional SDK binding (the vicon extra), imported only when chosen
    import pyvicon_datastream  # type: ignore[import-not-found]

    return pyvicon_datastream


def _open_backend(backend: str) -> tuple[Any, tuple[type[BaseException], ...]]:
    """Import the chosen SDK binding and build its adapter over a new client."""
    if backend not in BACKENDS:
        raise UserError(f"unknown Vicon SDK back end {backend!r}; use one of {', '.join(BACKENDS)}")
    tried = []
    for name in ("vicon_dssdk", "pyvicon"):
        if backend not in ("auto", name):
            continue
        try:
            mod = _import_dssdk() if name == "vicon_dssdk" else _import_pyvicon()
        except (ImportError, OSError) as exc:  # OSError: a binding whose native library fails
            tried.append(f"{name}: {exc}")
            continue
        if name == "vicon_dssdk":
            cls = mod.Client
            axes = getattr(cls, "AxisMapping", None)
            axis = None if axes is None else (axes.EForward, axes.ELeft, axes.EUp)
            return (_DSSDK(cls(), cls.StreamMode.EServerPush, axis),
                    (mod.DataStreamException, ValueError, TypeError))
        # the class is PyVicon in pyvicon_datastream 0.2.x, PyViconDatastream in early versions
        cls = getattr(mod, "PyVicon", None) or mod.PyViconDatastream
        return _PyVicon(cls(), mod), (Exception,)
    if backend == "auto":
        raise UserError("no Vicon DataStream SDK for Python is installed (neither vicon_dssdk nor "
                        f"pyvicon_datastream imports): {INSTALL_HINT}")
    what = ("pyvicon-datastream: pip install '.[vicon]'" if backend == "pyvicon"
            else "vicon_dssdk: install Vicon's DataStream SDK and its Python package")
    raise UserError(f"the {backend} back end is not importable ({tried[-1]}); {what}")


class ViconSDKSource:
    """Poses from a Vicon DataStream server.

    Args:
        host: ``HOST`` or ``HOST:PORT`` (default port 801).
        client: an object with the API of ``vicon_dssdk.ViconDataStream.Client`` or of
            ``pyvicon_datastream.PyVicon`` (tests pass fakes); default: a new client of
            the back end chosen by ``backend``.
        server_push: vicon_dssdk client given: the push constant for ``SetStreamMode``
            (None: leave the mode alone).
        clock: host clock, s (``time.time``).
        backend: ``auto`` (vicon_dssdk if it imports, else pyvicon), ``vicon_dssdk`` or
            ``pyvicon``. With a client given, ``auto`` tells the API from its methods.
        pv_module: pyvicon client given: the module with its ``Result``,
            ``StreamMode`` and ``Direction`` enums.
        axis_mapping: vicon_dssdk client given: the three ``AxisMapping`` values passed to
            ``SetAxisMapping`` (None: leave the SDK's default, Z-up).
        reconnect_period_s: wait between reconnection attempts after a lost connection.
    """

    in_table_frame = False

    def __init__(self, host: str, client: Any = None, server_push: Any = None,
                 clock: Callable[[], float] = time.time, connect_timeout_s: float = 10.0,
                 backend: str = "auto", pv_module: Any = None, axis_mapping: tuple | None = None,
                 reconnect_period_s: float = 0.5) -> None:
        self.host = _host_port(host)
        self.name = f"vicon-sdk:{self.host}"
        self.clock = clock
        self.reconnect_period_s = reconnect_period_s
        self.counters = {"frames": 0, "frame_errors": 0, "no_frame": 0, "bad_values": 0,
                         "subject_errors": 0, "disconnects": 0, "reconnects": 0}
        if client is None:
            self.sdk, self._exc = _open_backend(backend)
        else:
            if backend == "auto":
                backend = "vicon_dssdk" if hasattr(client, "GetFrame") else "pyvicon"
            if backend == "vicon_dssdk":
                self.sdk = _DSSDK(client, server_push, axis_mapping)
            elif backend == "pyvicon":
                if pv_module is None:
                    raise ValueError("a pyvicon client needs pv_module (its enums)")
                self.sdk = _PyVicon(client, pv_module)
            else:
                raise UserError(f"unknown Vicon SDK back end {backend!r}; use one of "
                                f"{', '.join(BACKENDS)}")
            self._exc = (Exception,)
        self.backend = self.sdk.name
        self.client = client if client is not None else self.sdk.c
        self._segments: dict[str, str] = {}
        self._connect(connect_timeout_s)

    # ------------------------------------------------------------ connection

    def _try_connect(self) -> str | None:
        """One attempt: connect and set up. None when ready, else why not."""
        try:
            self.sdk.connect(self.host)
        except Exception as exc:  # DataStreamException, _SetupError: try again
            why = str(exc) or type(exc).__name__
        else:
            why = "not connected"
        try:
            if not self.sdk.is_connected():
                return why
            self.sdk.setup()
        except Exception as exc:
            return f"set-up failed: {exc or type(exc).__name__}"
        self._segments.clear()
        return None

    def _connect(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            why = self._try_connect()
            if why is None:
                return
            if time.monotonic() > deadline:
                raise DeviceError(f"cannot connect to the Vicon DataStream server at {self.host} "
                                  f"({self.backend}: {why})")
            time.sleep(0.2)

    def _connected(self) -> bool:
        try:
            return self.sdk.is_connected()
        except Exception:
            return False

    def _reconnect(self, stop: threading.Event) -> None:
        while not stop.is_set():
            if self._try_connect() is None:
                self.counters["reconnects"] += 1
                _notice(f"reconnected to {self.host}")
                return
            stop.wait(self.reconnect_period_s)

    # ------------------------------------------------------------ frames

    def _segment(self, subject: str) -> str:
        seg = self._segments.get(subject)
        if seg is None:
            # The root segment is the ancestor of all the subject's segments (SDK manual);
            # for a Tracker object it is its only segment, named like the object.
            try:
                seg = self.sdk.root_segment(subject)
            except self._exc:
                seg = None
            if not seg:
                return subject  # not cached: asked again next frame
            self._segments[subject] = seg
        return seg

    def read_frame(self) -> list[PoseSample] | None:
        """Wait for the next frame (server push) and return its poses, or None."""
        sdk = self.sdk
        try:
            if not sdk.get_frame():
                self.counters["no_frame"] += 1
                return None
            frame = sdk.frame_number()
            latency = sdk.latency_s()
            subjects = sdk.subjects()
        except self._exc:
            self.counters["frame_errors"] += 1
            return None
        t_recv = self.clock()
        if not math.isfinite(latency) or latency < 0:
            latency = 0.0
        t = t_recv - latency
        out = []
        for subj in subjects:
            if not subj:
                self.counters["subject_errors"] += 1
                continue
            seg = self._segment(subj)
            try:
                p, occ_t = sdk.translation(subj, seg)
                q, occ_r = sdk.rotation_xyzw(subj, seg)
            except self._exc:
                self.counters["subject_errors"] += 1
                out.append(occluded_sample(subj, frame, t, t_recv))
                continue
            if occ_t or occ_r:
                out.append(occluded_sample(subj, frame, t, t_recv))
                continue
            sample = _pose(subj, frame, t, t_recv, p, q)
            if sample is None:
                self.counters["bad_values"] += 1
                sample = occluded_sample(subj, frame, t, t_recv)
            out.append(sample)
        self.counters["frames"] += 1
        return out

    def batches(self, stop: threading.Event) -> Iterator[list[PoseSample]]:
        while not stop.is_set():
            batch = self.read_frame()
            if batch:
                yield batch
            elif batch is None:
                if not self._connected():
                    self.counters["disconnects"] += 1
                    _notice(f"connection to {self.host} lost; reconnecting")
                    self._reconnect(stop)
                else:
                    stop.wait(0.01)  # server hiccup: do not spin

    def close(self) -> None:
        try:
            self.sdk.disconnect()
        except Exception:
            pass


def _host_port(host: str) -> str:
    name, sep, port = host.rpartition(":")
    if not sep:
        return f"{host}:{DEFAULT_PORT}"
    if not name or not port.isdigit() or not 0 < int(port) <= 65535:
        raise UserError(f"bad Vicon DataStream address {host!r}; use HOST or HOST:PORT")
    return host


def _pose(subj: str, frame: int, t: float, t_recv: float, p: Any, q: Any) -> PoseSample | None:
    """Pose in metres from translation (mm) and quaternion (x, y, z, w); None if unusable."""
    try:
        tx, ty, tz = (float(v) for v in p)
        qx, qy, qz, qw = (float(v) for v in q)
    except (TypeError, ValueError):
        return None
    vals = (tx, ty, tz, qx, qy, qz, qw)
    if not all(math.isfinite(v) for v in vals):
        return None
    norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    if abs(norm - 1.0) > 1e-3:
        return None
    return PoseSample(subj, frame, t, t_recv, tx * 1e-3, ty * 1e-3, tz * 1e-3,
                      qx / norm, qy / norm, qz / norm, qw / norm)
