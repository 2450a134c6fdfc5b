"""Real autopilot firmware as a child process: ArduCopter SITL or PX4 SITL with SIH (../shared/sitl).

API (stable; the firmware tests and the closed loop use it):

    from sim.firmware import ArduPilotSitl, Px4Sih, sitl_root, connect

    with ArduPilotSitl(speedup=5) as fw:            # or Px4Sih(speed_factor=1)
        gcs = connect(fw.gcs_url)                   # pymavlink link for a test / ground station
        fw.wait_heartbeat(gcs, timeout=30)
        fw.arm_takeoff(gcs, altitude_m=10)          # ArduPilot: GUIDED, waits for the EKF; PX4: auto takeoff
        ... the daemon gets fw.companion_url (its mavlink.url) ...
    # leaving the block stops the process by its PID and removes its temporary working directory

- `sitl_root()`: the firmware folder: env JSAR_SITL_ROOT, else ../shared/sitl beside the repository.
  `firmware_missing(kind)` says why a kind ("arducopter" / "px4") cannot run, None when it can.
- Each instance runs in its own temporary working directory with its own instance number (ArduPilot
  `-I N`, PX4 `-i N`), taken from a lock file so instances run side by side (tests, closed loop), and
  its own free loopback UDP ports. The firmware sends to ports we listen on: every URL below is a
  pymavlink `udpin:127.0.0.1:PORT` (the listener replies to the firmware's source port).
- `gcs_url`: a ground-station link (ArduPilot SERIAL0; PX4's GCS link). `companion_url`: a second link for
  the companion computer (ArduPilot SERIAL1; PX4's onboard/API link). `extra_urls`: ArduPilot's SERIAL2
  when `links=3` (PX4 has only the two).
- `system_id`: the autopilot's MAVLink system id (ArduPilot 1; PX4 instance + 1); component 1.
- Waiting is on messages with a timeout (TimeoutError naming what did not arrive), never on sleeps.
- Speed: ArduPilot `--speedup N` (also settable at run time: `set_speedup`, parameter SIM_SPEEDUP, so a test
  can fast-forward the 30-40 s position-estimate wait and then run in real time); PX4
  `PX4_SIM_SPEED_FACTOR`.
- `restart()`: stop and start the same instance again (same working directory, parameters and ports):
  an autopilot reboot as a ground station sees it.
- Things the firmware does that a caller must know (docs/sim.md, "Mock versus firmware"): a pymavlink
  udpin link sends nothing before it has heard the firmware (wait for a heartbeat first); ArduPilot sends
  no telemetry on a port until asked (`set_message_interval`), and a request in its first ~3 s is
  acknowledged but not acted on; PX4 boots in about 5 s. PX4's px4/bin holds its command links as
  3-byte files (a copy of symlinks): a bin/ of real links in the working directory goes first on PATH.
"""
from __future__ import annotations

import fcntl
import math
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

os.environ.setdefault("MAVLINK20", "1")  # pymavlink's MAVLink 2 dialect (gimbal messages) must load first
from pymavlink import mavutil  # noqa: E402

from sim.ports import free_udp_port, free_udp_ports  # noqa: E402

REPO_ROOT = Path(__file__).resolve().parent.parent
M = mavutil.mavlink

COPTER_GUIDED = 4  # ArduCopter custom_mode numbers
COPTER_LOITER = 5
COPTER_BRAKE = 17
PX4_MAIN_OFFBOARD = 6  # PX4 main modes (custom_mode bits 16-23)
PX4_MAIN_AUTO = 4
PX4_MAIN_POSCTL = 3


def sitl_root() -> Path:
    """The firmware folder, absolute: $JSAR_SITL_ROOT (a relative one from the working directory, since the
    firmware runs in a folder of its own), else ../shared/sitl next to the repository."""
    env = os.environ.get("JSAR_SITL_ROOT")
    return Path(env).resolve() if env else REPO_ROOT.parent / "shared" / "sitl"


def firmware_missing(kind: str) -> str | None:
    """Why firmware `kind` ("arducopter" / "px4") cannot run here, or None when it can."""
    root = sitl_root()
    path = root / "arducopter" if kind == "arducopter" else root / "px4" / "run.sh"
    if kind not in ("arducopter", "px4"):
        raise ValueError(f"unknown firmware kind {kind!r} (arducopter, px4)")
    if not path.exists():
        return f"no {kind} firmware at {path} (set JSAR_SITL_ROOT to the folder holding arducopter and px4/)"
    if not os.access(path, os.X_OK):
        return f"{path} is not executable"
    return None


def connect(url: str, source_system: int = 255, source_component: int = 190) -> Any:
    """A pymavlink connection (default identity: a ground station, 255/190)."""
    return mavutil.mavlink_connection(url, source_system=source_system, source_component=source_component,
                                      autoreconnect=True)


def _claim_instance(kind: str, first: int, last: int) -> tuple[int, Any]:
    """The lowest instance number in first..last nobody else holds (lock file in the temp dir), with the
    open locked file (closing it frees the number); RuntimeError when all are taken."""
    for number in range(first, last + 1):
        handle = open(Path(tempfile.gettempdir()) / f"jsar-sitl-{kind}-{number}.lock", "w")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return number, handle
    raise RuntimeError(f"all {kind} instance numbers {first}..{last} are in use")


def wait_message(conn: Any, types: str | list[str], timeout: float,
                 condition: Callable[[Any], bool] = lambda _msg: True, what: str = "",
                 heartbeat: bool = True) -> Any:
    """The next message of `types` meeting `condition` within `timeout` s (TimeoutError otherwise); sends a
    ground-station HEARTBEAT each second meanwhile when `heartbeat`."""
    deadline = time.monotonic() + timeout
    next_heartbeat = 0.0
    while True:
        now = time.monotonic()
        if now >= deadline:
            raise TimeoutError(f"no {what or types} within {timeout:.0f} s")
        if heartbeat and now >= next_heartbeat:
            conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            next_heartbeat = now + 1.0
        msg = conn.recv_match(type=types, blocking=True, timeout=min(0.5, deadline - now))
        if msg is not None and msg.get_type() != "BAD_DATA" and condition(msg):
            return msg


def command(conn: Any, target: tuple[int, int], cmd: int, params: list[float], timeout: float = 3.0) -> int:
    """Send COMMAND_LONG `cmd` (params padded to 7) to target (sysid, compid); its COMMAND_ACK result."""
    padded = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(target[0], target[1], cmd, 0, *padded)
    ack = wait_message(conn, "COMMAND_ACK", timeout, lambda m: m.command == cmd, what=f"COMMAND_ACK for {cmd}")
    return int(ack.result)


def set_message_interval(conn: Any, target: tuple[int, int], msg_id: int, hz: float) -> int:
    """MAV_CMD_SET_MESSAGE_INTERVAL for `msg_id` at `hz` (0 = off); the ack result."""
    interval_us = -1 if hz <= 0 else int(1e6 / hz)
    return command(conn, target, M.MAV_CMD_SET_MESSAGE_INTERVAL, [msg_id, interval_us])


def set_param(conn: Any, target: tuple[int, int], name: str, value: float, timeout: float = 5.0) -> float:
    """PARAM_SET `name`=value (as a float, as ArduPilot takes every parameter); the echoed PARAM_VALUE."""
    conn.mav.param_set_send(target[0], target[1], name.encode(), float(value), M.MAV_PARAM_TYPE_REAL32)
    echo = wait_message(conn, "PARAM_VALUE", timeout, lambda m: m.param_id == name, what=f"PARAM_VALUE {name}")
    return float(echo.param_value)


def armed(heartbeat: Any) -> bool:
    """Whether a HEARTBEAT says the vehicle is armed."""
    return bool(heartbeat.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)


def euler_deg(q: list[float]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in degrees of a quaternion [w, x, y, z] (ZYX Tait-Bryan)."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)


class Firmware:
    """A firmware child process (base of ArduPilotSitl / Px4Sih); a context manager that stops it."""

    kind = ""
    system_id = 1
    component_id = 1

    def __init__(self, instance: int | None = None, links: int = 2) -> None:
        missing = firmware_missing(self.kind)
        if missing:
            raise FileNotFoundError(missing)
        self.root = sitl_root()
        if instance is None:
            self.instance, self._lock = _claim_instance(self.kind, 10, 39)
        else:
            self.instance, self._lock = instance, None
        self.ports = [free_udp_port() for _ in range(links)]
        self.workdir = Path(tempfile.mkdtemp(prefix=f"jsar-{self.kind}-{self.instance}-"))
        self.log_path = self.workdir / "firmware.log"
        self.process: subprocess.Popen[bytes] | None = None

    @property
    def target(self) -> tuple[int, int]:
        """(system id, component id) of the autopilot."""
        return self.system_id, self.component_id

    @property
    def gcs_url(self) -> str:
        """pymavlink URL of the ground-station link."""
        return f"udpin:127.0.0.1:{self.ports[0]}"

    @property
    def companion_url(self) -> str:
        """pymavlink URL of the companion-computer link (the daemon's mavlink.url)."""
        return f"udpin:127.0.0.1:{self.ports[1]}"

    @property
    def extra_urls(self) -> list[str]:
        """pymavlink URLs of further links (ArduPilot's SERIAL2 with links=3)."""
        return [f"udpin:127.0.0.1:{port}" for port in self.ports[2:]]

    @property
    def pid(self) -> int:
        """The firmware process id (RuntimeError before start)."""
        if self.process is None:
            raise RuntimeError(f"{self.kind} is not running")
        return self.process.pid

    def _command_line(self) -> tuple[list[str], dict[str, str]]:
        raise NotImplementedError

    def start(self) -> "Firmware":
        """Start the process (returns self); its output goes to log_path."""
        argv, env = self._command_line()
        with open(self.log_path, "ab") as log:
            self.process = subprocess.Popen(argv, cwd=self.workdir, env=env, stdout=log, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL, start_new_session=True)
        return self

    def running(self) -> bool:
        """Whether the process is alive."""
        return self.process is not None and self.process.poll() is None

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the process by its PID: SIGINT, then SIGKILL after `timeout` s."""
        if self.process is None:
            return
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout)
        self.process = None

    def restart(self) -> None:
        """Stop and start the same instance again (same working directory, parameters, ports)."""
        self.stop()
        self.start()

    def log_tail(self, chars: int = 3000) -> str:
        """The end of the firmware's output (for failure messages)."""
        try:
            return self.log_path.read_text(errors="replace")[-chars:]
        except OSError:
            return ""

    def close(self) -> None:
        """Stop the process, free the instance number and remove the working directory."""
        try:
            self.stop()
        finally:
            if self._lock is not None:
                self._lock.close()
                self._lock = None
            shutil.rmtree(self.workdir, ignore_errors=True)

    def __enter__(self) -> "Firmware":
        return self.start() if self.process is None else self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def wait_heartbeat(self, conn: Any, timeout: float = 30.0) -> Any:
        """The autopilot's first HEARTBEAT on `conn` (TimeoutError with the firmware's log otherwise)."""
        try:
            return wait_message(conn, "HEARTBEAT", timeout,
                                lambda m: m.get_srcSystem() == self.system_id and m.get_srcComponent() == 1,
                                what=f"{self.kind} HEARTBEAT")
        except TimeoutError as exc:
            raise TimeoutError(f"{exc}; running={self.running()}; log:\n{self.log_tail()}") from exc

    def mode(self, conn: Any, timeout: float = 5.0) -> int:
        """The autopilot's custom_mode from its next HEARTBEAT."""
        return int(self.wait_heartbeat(conn, timeout).custom_mode)

    def arm(self, conn: Any, timeout: float) -> None:
        """Arm (MAV_CMD_COMPONENT_ARM_DISARM), retrying on each denial until `timeout` s; the denial's
        STATUSTEXT in the TimeoutError."""
        deadline = time.monotonic() + timeout
        last_text = ""
        while time.monotonic() < deadline:
            result = command(conn, self.target, M.MAV_CMD_COMPONENT_ARM_DISARM, [1])
            if result == M.MAV_RESULT_ACCEPTED:
                wait_message(conn, "HEARTBEAT", max(1.0, deadline - time.monotonic()),
                             lambda m: m.get_srcSystem() == self.system_id and m.get_srcComponent() == 1 and armed(m),
                             what="an armed HEARTBEAT")
                return
            try:  # the reason, and a pause on the firmware's own clock before the next try
                text = wait_message(conn, "STATUSTEXT", min(2.0, max(0.1, deadline - time.monotonic())),
                                    what="STATUSTEXT")
                last_text = text.text
            except TimeoutError:
                pass
        raise TimeoutError(f"{self.kind} would not arm within {timeout:.0f} s (last: {last_text!r})")

    def local_position(self, conn: Any, timeout: float = 5.0) -> Any:
        """The next LOCAL_POSITION_NED (x, y, z m; vx, vy, vz m/s; NED from the EKF origin)."""
        return wait_message(conn, "LOCAL_POSITION_NED", timeout, what="LOCAL_POSITION_NED")


class ArduPilotSitl(Firmware):
    """ArduCopter SITL (`arducopter --model +`) with ArduPilot's copter defaults and a servo gimbal.

    `speedup`: simulation speed over real time (`--speedup`); `params`: extra defaults (name -> value)
    written to a parameter file loaded after copter.parm and gimbal.parm."""

    kind = "arducopter"

    def __init__(self, instance: int | None = None, speedup: float = 1.0, links: int = 2,
                 params: dict[str, float] | None = None) -> None:
        if not 1 <= links <= 3:
            raise ValueError(f"links must be 1..3 (SERIAL0..2), got {links}")
        super().__init__(instance, links)
        self.speedup = speedup
        self.params = dict(params or {})

    def _command_line(self) -> tuple[list[str], dict[str, str]]:
        defaults = [str(self.root / "copter.parm"), str(self.root / "gimbal.parm")]
        if self.params:
            extra = self.workdir / "extra.parm"
            extra.write_text("".join(f"{k} {v}\n" for k, v in self.params.items()), encoding="ascii")
            defaults.append(str(extra))
        argv = [str(self.root / "arducopter"), "--model", "+", "--speedup", f"{self.speedup:g}",
                "-I", str(self.instance), "--defaults", ",".join(defaults)]
        for serial, port in enumerate(self.ports):
            argv += [f"--serial{serial}", f"udpclient:127.0.0.1:{port}"]
        return argv, dict(os.environ)

    def set_speedup(self, conn: Any, speedup: float) -> None:
        """Change the simulation speed at run time (parameter SIM_SPEEDUP)."""
        set_param(conn, self.target, "SIM_SPEEDUP", speedup)
        self.speedup = speedup

    def set_mode(self, conn: Any, custom_mode: int, timeout: float = 5.0) -> None:
        """Switch to ArduCopter mode `custom_mode` (MAV_CMD_DO_SET_MODE) and wait for the HEARTBEAT showing it."""
        result = command(conn, self.target, M.MAV_CMD_DO_SET_MODE,
                         [M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode])
        if result != M.MAV_RESULT_ACCEPTED:
            raise RuntimeError(f"mode {custom_mode} refused (result {result})")
        wait_message(conn, "HEARTBEAT", timeout, lambda m: m.get_srcSystem() == self.system_id
                     and m.get_srcComponent() == 1 and m.custom_mode == custom_mode, what=f"mode {custom_mode}")

    def wait_position_estimate(self, conn: Any, timeout: float = 90.0) -> None:
        """Wait until the EKF reports an absolute horizontal position (EKF_STATUS_REPORT), which GUIDED
        needs to arm ("Need Position Estimate" before); asks for the report at 2 Hz."""
        set_message_interval(conn, self.target, M.MAVLINK_MSG_ID_EKF_STATUS_REPORT, 2)
        needed = M.EKF_POS_HORIZ_ABS | M.EKF_PRED_POS_HORIZ_ABS | M.EKF_VELOCITY_HORIZ
        wait_message(conn, "EKF_STATUS_REPORT", timeout,
                     lambda m: (m.flags & needed) == needed and not m.flags & M.EKF_CONST_POS_MODE,
                     what="an EKF position estimate")

    def arm_takeoff(self, conn: Any, altitude_m: float = 10.0, timeout: float = 120.0) -> Any:
        """GUIDED, wait for the position estimate, arm, take off to `altitude_m` (m above home); returns the
        LOCAL_POSITION_NED at >= 90 % of the altitude. Streams LOCAL_POSITION_NED at 10 Hz on `conn`."""
        deadline = time.monotonic() + timeout
        set_message_interval(conn, self.target, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 10)
        self.wait_position_estimate(conn, timeout)
        self.set_mode(conn, COPTER_GUIDED)
        self.arm(conn, max(5.0, deadline - time.monotonic()))
        result = command(conn, self.target, M.MAV_CMD_NAV_TAKEOFF, [0, 0, 0, math.nan, 0, 0, altitude_m])
        if result != M.MAV_RESULT_ACCEPTED:
            raise RuntimeError(f"takeoff refused (result {result})")
        return wait_message(conn, "LOCAL_POSITION_NED", max(5.0, deadline - time.monotonic()),
                            lambda m: -m.z >= 0.9 * altitude_m, what=f"altitude {altitude_m} m")


class Px4Sih(Firmware):
    """PX4 SITL with SIH (quadrotor, `px4/run.sh`). `params`: boot parameters (PX4_PARAM_<NAME>); the
    defaults give the gimbal manager v2 without a gimbal device (MNT_MODE_IN 4, MNT_MODE_OUT 0) and no
    logging (SDLOG_MODE -1). `speed_factor`: PX4_SIM_SPEED_FACTOR."""

    kind = "px4"
    DEFAULT_PARAMS = {"MNT_MODE_IN": 4, "MNT_MODE_OUT": 0, "SDLOG_MODE": -1}

    def __init__(self, instance: int | None = None, speed_factor: float = 1.0,
                 params: dict[str, float] | None = None) -> None:
        super().__init__(instance, links=2)
        self.system_id = self.instance + 1
        self.speed_factor = speed_factor
        self.params = {**self.DEFAULT_PARAMS, **(params or {})}
        self.listen_ports = free_udp_ports(2)  # PX4's own GCS / API ports

    def _command_line(self) -> tuple[list[str], dict[str, str]]:
        env = dict(os.environ)
        env.update({f"PX4_PARAM_{k}": f"{v:g}" if isinstance(v, float) else str(v) for k, v in self.params.items()})
        if self.speed_factor != 1.0:
            env["PX4_SIM_SPEED_FACTOR"] = f"{self.speed_factor:g}"
        env["PATH"] = f"{self._command_links()}{os.pathsep}{env.get('PATH', '')}"
        argv = [str(self.root / "px4" / "run.sh"), "-w", str(self.workdir / "px4"), "-i", str(self.instance),
                "-g", str(self.ports[0]), "-G", str(self.listen_ports[0]),
                "-o", str(self.ports[1]), "-O", str(self.listen_ports[1])]
        return argv, env

    def _command_links(self) -> Path:
        """A folder of px4-MODULE links to bin/px4 for those of px4/bin that are not executable (copies of
        the build's symlinks as 3-byte files "px4"); first on PATH, where PX4's start script finds them."""
        links = self.workdir / "bin"
        links.mkdir(exist_ok=True)
        binary = self.root / "px4" / "bin" / "px4"
        for entry in (self.root / "px4" / "bin").glob("px4-*"):
            if entry.suffix != ".sh" and not os.access(entry, os.X_OK) and not (links / entry.name).exists():
                (links / entry.name).symlink_to(binary)
        return links

    def set_mode(self, conn: Any, main_mode: int, sub_mode: int = 0, timeout: float = 5.0) -> int:
        """Ask for PX4 main mode `main_mode` (MAV_CMD_DO_SET_MODE); returns the ack result (PX4 refuses
        OFFBOARD without a setpoint stream); when accepted, waits for the HEARTBEAT showing it."""
        result = command(conn, self.target, M.MAV_CMD_DO_SET_MODE,
                         [M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main_mode, sub_mode])
        if result == M.MAV_RESULT_ACCEPTED:
            wait_message(conn, "HEARTBEAT", timeout, lambda m: m.get_srcSystem() == self.system_id
                         and m.get_srcComponent() == 1 and px4_main_mode(m.custom_mode) == main_mode,
                         what=f"PX4 main mode {main_mode}")
        return result

    def wait_position_estimate(self, conn: Any, timeout: float = 60.0) -> None:
        """Wait for HOME_POSITION (PX4 sets home once it has a global position estimate)."""
        set_message_interval(conn, self.target, M.MAVLINK_MSG_ID_HOME_POSITION, 1)
        wait_message(conn, "HOME_POSITION", timeout, what="HOME_POSITION")

    def arm_takeoff(self, conn: Any, altitude_m: float = 2.5, timeout: float = 60.0) -> Any:
        """Wait for home, arm, MAV_CMD_NAV_TAKEOFF (PX4 climbs to MIS_TAKEOFF_ALT, 2.5 m by default, when
        altitude_m is NaN or is taken as is otherwise); returns LOCAL_POSITION_NED at >= 80 % of it."""
        deadline = time.monotonic() + timeout
        self.wait_position_estimate(conn, timeout)
        self.arm(conn, max(5.0, deadline - time.monotonic()))
        home = wait_message(conn, "GLOBAL_POSITION_INT", 5.0, what="GLOBAL_POSITION_INT")
        result = command(conn, self.target, M.MAV_CMD_NAV_TAKEOFF,
                         [math.nan, 0, 0, math.nan, math.nan, math.nan, home.alt / 1000.0 + altitude_m])
        if result != M.MAV_RESULT_ACCEPTED:
            raise RuntimeError(f"takeoff refused (result {result})")
        return wait_message(conn, "LOCAL_POSITION_NED", max(5.0, deadline - time.monotonic()),
                            lambda m: -m.z >= 0.8 * altitude_m, what=f"altitude {altitude_m} m")

    def start_offboard(self, conn: Any, send_setpoint: Callable[[], None] | None = None,
                       lead_s: float = 2.0, rate_hz: float = 10.0) -> int:
        """Switch to OFFBOARD. With `send_setpoint` (one setpoint per call), first streams it at `rate_hz`
        for `lead_s` s, paced on the incoming messages (PX4 needs a > 2 Hz stream before the switch);
        without it the caller (e.g. the daemon) must already be streaming. Returns the ack result."""
        if send_setpoint is not None:
            end = time.monotonic() + lead_s
            while time.monotonic() < end:
                send_setpoint()
                next_at = time.monotonic() + 1.0 / rate_hz
                while time.monotonic() < next_at:
                    conn.recv_match(blocking=True, timeout=max(0.0, next_at - time.monotonic()))
        return self.set_mode(conn, PX4_MAIN_OFFBOARD)


def px4_main_mode(custom_mode: int) -> int:
    """PX4's main mode from a HEARTBEAT custom_mode (bits 16-23)."""
    return (int(custom_mode) >> 16) & 0xFF


def velocity_setpoint(conn: Any, target: tuple[int, int], vn: float, ve: float, vd: float,
                      yaw_rate: float = 0.0) -> None:
    """One SET_POSITION_TARGET_LOCAL_NED with velocity (m/s, NED) and yaw rate (rad/s) only."""
    mask = 0b0000010111000111  # ignore position, acceleration and yaw; use velocity and yaw rate
    conn.mav.set_position_target_local_ned_send(0, target[0], target[1], M.MAV_FRAME_LOCAL_NED, mask,
                                                0, 0, 0, vn, ve, vd, 0, 0, 0, 0, yaw_rate)
