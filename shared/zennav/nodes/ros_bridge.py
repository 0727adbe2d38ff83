"""The ROS 2 bridge's core, transport-free: ROS sensor messages in, zennav's sensor stream out; zennav's solution
in, ROS messages out. Frames are converted here, once (zennav.rosframes: ROS REP-103/105 ENU and FLU <-> NED
and FRD); ROS stamps are Unix time, zennav's GPS time (zennav.gpstime).

In (``RosInput``): sensor_msgs/Imu (angular velocity [rad/s] and linear acceleration [m/s^2], FLU) becomes imu
messages of angle and velocity increments (FRD) over the interval since the previous sample (trapezoidal);
sensor_msgs/NavSatFix (degrees, ellipsoidal altitude, ENU covariance [m^2]) becomes gnss messages (std NED
from the covariance diagonal, ``default_std_m`` when the covariance type is unknown; status NO_FIX -> fix NONE,
FIX -> SINGLE, SBAS/GBAS -> DGPS; satellite count unknown). The stream starts (stream_start) once two fixes
and an IMU sample after them are in: position from the last fix, velocity from the two fixes' difference,
attitude from the IMU message's orientation when it has one (orientation_covariance[0] >= 0), else heading
unknown (the ins aligns); that IMU sample's time is the initial time, the stream's samples follow it. Samples
are handed out in time order: one waits until an IMU sample ``latency_s`` of data time newer has arrived (the
IMU is the clock: a fix that arrives before the IMU samples of its time, their subscription lagging behind,
waits for them; a fix that comes later than that is dropped, ``late_fix``). Rejections are counted by reason:
``bad_imu`` (non-finite), ``imu_out_of_order``, ``fix_out_of_order``, ``bad_fix``, ``late_fix``.

Out (``ros_outputs``): a nav_solution becomes sensor_msgs/NavSatFix (degrees, ENU covariance, diagonal known),
nav_msgs/Odometry (frame ``map``: ENU metres from the first solution; child ``base_link``: orientation FLU in ENU,
linear velocity in base_link; angular velocity not estimated: its covariance -1) and sensor_msgs/Imu with the
orientation only (angular velocity and acceleration covariances -1: not provided, as the message defines).
"""
from __future__ import annotations

import heapq
import math
from collections import Counter
from dataclasses import replace

import numpy as np

from .. import messages as M
from ..gpstime import gps_ns_to_unix_ns, unix_ns_to_gps_ns
from ..nav import earth
from ..nav.rotation import quat_to_dcm, quat_to_euler
from ..nav.types import NS, FixType, GnssFix, ImuNoise, InitialState, NavConfig
from ..params import sensor_map
from ..rmw import header, stamp_ns, typestore
from ..rosframes import C_FRD_FLU, cov_ned_to_enu, q_enu_flu_to_q_nb, q_nb_to_q_enu_flu

IMU_TYPE, FIX_TYPE, ODOM_TYPE = "sensor_msgs/msg/Imu", "sensor_msgs/msg/NavSatFix", "nav_msgs/msg/Odometry"
NAVSAT_FIX = {-1: FixType.NONE, 0: FixType.SINGLE, 1: FixType.DGPS, 2: FixType.DGPS}


class RosInput:
    """ROS Imu / NavSatFix (rosbags objects) -> zennav stream messages ((kind, message) lists, cseq stamped)."""

    def __init__(self, name: str, imu_noise: ImuNoise, lever_arm_b, latency_s: float = 0.2,
                 default_std_m: float = 5.0):
        self.name = name
        self.config = NavConfig(imu_noise=imu_noise, lever_arm_b=np.asarray(lever_arm_b, dtype=float))
        self.latency_ns = int(latency_s * NS)
        self.default_std_m = default_std_m
        self.counts: Counter[str] = Counter()
        self.started = False
        self.cseq = 0
        self.n = {"imu": 0, "gnss": 0}
        self._heap: list = []
        self._k = 0
        self._last_fix_t = -1
        self._first_fixes: list[GnssFix] = []  # the last two fixes released before the stream started
        self._prev_imu: tuple[int, np.ndarray, np.ndarray] | None = None
        self._last_out_t = -1
        self._newest = -1  # [ns] the newest IMU sample's time
        self._q_nb: np.ndarray | None = None
        self._q_std: float | None = None

    # ---------------------------------------------------------------- in
    def on_imu(self, msg) -> list[tuple[str, dict]]:
        t = unix_ns_to_gps_ns(stamp_ns(msg.header))
        w = np.array([msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z]) @ C_FRD_FLU.T
        f = np.array([msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z]) @ C_FRD_FLU.T
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(f))):
            self.counts["bad_imu"] += 1
            return []
        prev = self._prev_imu
        if prev is not None and t <= prev[0]:
            self.counts["imu_out_of_order"] += 1
            return []
        self._prev_imu = (t, w, f)
        if msg.orientation_covariance[0] >= 0.0:
            o = msg.orientation
            self._q_nb = q_enu_flu_to_q_nb([o.w, o.x, o.y, o.z])
            self._q_std = math.sqrt(max(msg.orientation_covariance[8], 0.0))
        if prev is None:
            return []
        dt = (t - prev[0]) / NS
        self._push(t, 1, ("imu", t, t - prev[0], 0.5 * (w + prev[1]) * dt, 0.5 * (f + prev[2]) * dt))
        self._newest = t
        return self._release()

    def on_fix(self, msg) -> list[tuple[str, dict]]:
        t = unix_ns_to_gps_ns(stamp_ns(msg.header))
        llh = np.array([math.radians(msg.latitude), math.radians(msg.longitude), msg.altitude])
        cov = np.asarray(msg.position_covariance, dtype=float).reshape(3, 3)
        if msg.position_covariance_type == 0:
            std = np.full(3, self.default_std_m)
        else:
            std = np.sqrt(np.clip(np.diag(cov_ned_to_enu(cov)), 0.0, None))  # ENU -> NED (the map is symmetric)
        if not (np.all(np.isfinite(llh)) and np.all(np.isfinite(std))):
            self.counts["bad_fix"] += 1
            return []
        if t <= self._last_fix_t:
            self.counts["fix_out_of_order"] += 1
            return []
        self._last_fix_t = t
        fix = GnssFix(t, llh, std, fix=int(NAVSAT_FIX.get(int(msg.status.status), FixType.NONE)), num_sats=-1)
        if t <= self._last_out_t:
            self.counts["late_fix"] += 1
            return []
        self._push(t, 0, ("gnss", fix))
        return self._release()

    def _push(self, t: int, order: int, item) -> None:
        self._k += 1
        heapq.heappush(self._heap, (t, order, self._k, item))

    def _release(self, flush: bool = False) -> list[tuple[str, dict]]:
        out: list[tuple[str, dict]] = []
        heap = self._heap
        while heap and (flush or heap[0][0] <= self._newest - self.latency_ns):
            t, _o, _k, item = heapq.heappop(heap)
            if not self.started:
                if item[0] == "gnss" and item[1].fix != FixType.NONE:
                    self._first_fixes = [*self._first_fixes[-1:], item[1]]
                elif item[0] == "imu" and len(self._first_fixes) == 2:
                    out.append(self._start(t))  # this sample's time is the initial state's: the next one is first
                    self._last_out_t = t
                continue  # before the stream starts: nothing to navigate from yet
            self.cseq += 1
            self._last_out_t = t
            if item[0] == "imu":
                _kind, t, dt, dtheta, dvel = item
                out.append(("imu", M.imu_msg(t, dtheta, dvel, dt, self.cseq)))
            else:
                out.append(("gnss", M.gnss_msg(item[1], self.cseq)))
            self.n[item[0]] += 1
        return out

    def _start(self, t: int) -> tuple[str, dict]:
        a, b = self._first_fixes
        dt = (b.t_ns - a.t_ns) / NS
        v_n = np.array(earth.dllh_to_ned(b.llh - a.llh, b.llh[0], b.llh[2]), dtype=float) / dt
        std_v = float(np.max(b.std_ned)) * math.sqrt(2.0) / dt + 0.5
        known = self._q_nb is not None
        euler = quat_to_euler(self._q_nb) if known else np.zeros(3)
        att_std = max(self._q_std or 0.0, math.radians(0.5))
        init = InitialState(t_ns=t, llh=b.llh.copy(), v_n=v_n, euler=euler, std_pos_ned=b.std_ned.copy(),
                            std_v_n=np.full(3, std_v), std_euler=np.array([att_std] * 2 + [max(att_std, 0.02)]),
                            heading_known=known)
        self.started = True
        self.cseq = 0
        config = replace(self.config, start_t_ns=t)
        return "stream", M.make("stream_start", t, cseq=0, dataset=self.name, config=sensor_map(config),
                                initial=M.dataclass_to_map(init), counts={"imu": -1, "gnss": -1}, outages=[])

    def end(self) -> list[tuple[str, dict]]:
        """Everything held, then stream_end (the bridge is stopping)."""
        out = self._release(flush=True)
        if self.started:
            self.cseq += 1
            out.append(("stream", M.make("stream_end", max(self._last_out_t, 0), cseq=self.cseq,
                                         counts=dict(self.n), last_cseq=self.cseq)))
        return out


# -------------------------------------------------------------------- out
def ros_outputs(msg: dict, origin_llh: np.ndarray, frame: str = "base_link") -> dict[str, object]:
    """A nav_solution -> {'fix': NavSatFix, 'odom': Odometry, 'imu': Imu} (rosbags objects); origin_llh: the
    ENU origin of the odometry [rad, rad, m]."""
    T = typestore().types
    unix_ns = gps_ns_to_unix_ns(msg["t_ns"])
    llh = np.asarray(msg["llh"], dtype=float)
    std = np.asarray(msg["std_pos_ned"], dtype=float)
    cov_enu = cov_ned_to_enu(np.diag(std * std))
    fix = T[FIX_TYPE](header=header(unix_ns, frame),
                      status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                      latitude=math.degrees(llh[0]), longitude=math.degrees(llh[1]), altitude=float(llh[2]),
                      position_covariance=cov_enu.ravel(), position_covariance_type=2)
    q = q_nb_to_q_enu_flu(msg["q_nb"])
    quat = T["geometry_msgs/msg/Quaternion"](x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0]))
    n, e, d = earth.dllh_to_ned(llh - origin_llh, origin_llh[0], origin_llh[2])
    pose_cov = np.zeros((6, 6))
    pose_cov[:3, :3] = cov_enu
    std_att = np.asarray(msg["std_euler"], dtype=float)
    pose_cov[3:, 3:] = np.diag(std_att * std_att)
    C_nb = quat_to_dcm(np.asarray(msg["q_nb"], dtype=float))
    v_flu = C_FRD_FLU @ C_nb.T @ np.asarray(msg["v_n"], dtype=float)  # FRD -> FLU (the matrix is symmetric)
    std_v = np.asarray(msg["std_v_n"], dtype=float)
    twist_cov = np.zeros((6, 6))
    twist_cov[:3, :3] = C_FRD_FLU @ C_nb.T @ np.diag(std_v * std_v) @ C_nb @ C_FRD_FLU
    twist_cov[3, 3] = -1.0
    vec = T["geometry_msgs/msg/Vector3"]
    odom = T[ODOM_TYPE](
        header=header(unix_ns, "map"), child_frame_id=frame,
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=float(e), y=float(n),
                                                                                 z=float(-d)), orientation=quat),
            covariance=pose_cov.ravel()),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=vec(x=float(v_flu[0]), y=float(v_flu[1]), z=float(v_flu[2])),
                                               angular=vec(x=0.0, y=0.0, z=0.0)),
            covariance=twist_cov.ravel()))
    unknown = np.zeros(9)
    unknown[0] = -1.0
    imu = T[IMU_TYPE](header=header(unix_ns, frame), orientation=quat,
                      orientation_covariance=np.diag(std_att * std_att).ravel(),
                      angular_velocity=vec(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=unknown.copy(),
                      linear_acceleration=vec(x=0.0, y=0.0, z=0.0), linear_acceleration_covariance=unknown.copy())
    return {"fix": fix, "odom": odom, "imu": imu}

