"""Closed-loop synthetic scene: a textured ground plane seen by a gimbal camera, a car that turns and
passes under tree canopies / a bridge, and the ground-truth box of the car in every frame.

Conventions: world = local NED metres (north, east, down), ground plane at down = 0. Camera pose =
position (north, east, altitude above ground, metres) + earth-frame yaw (radians, clockwise from
north) + earth-frame pitch (radians, 0 = horizon, negative = down), no roll (stabilised gimbal).
Image coordinates: pixels, origin top-left, x right, y down; boxes (x, y, w, h) in pixels.
Occluders are drawn on the ground plane (a canopy's height is ignored: from 40 m up the parallax of a
5 m tree is a few pixels). Everything is a pure function of the seed and the time: no global state.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np


@dataclass(frozen=True)
class CameraConfig:
    """Pinhole camera: image size in pixels, horizontal field of view in degrees (square pixels)."""

    width: int = 640
    height: int = 480
    hfov_deg: float = 50.0

    def __post_init__(self) -> None:
        if self.width < 16 or self.height < 16:
            raise ValueError(f"camera size must be at least 16x16, got {self.width}x{self.height}")
        if not 5.0 <= self.hfov_deg <= 150.0:
            raise ValueError(f"hfov_deg must be in 5..150, got {self.hfov_deg}")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels."""
        return 0.5 * self.width / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view in degrees."""
        return math.degrees(2.0 * math.atan(0.5 * self.height / self.focal_px))


@dataclass(frozen=True)
class SceneConfig:
    """Scene parameters; every random choice derives from `seed`."""

    seed: int = 0
    texture: str = "auto"  # "auto": real frames from JSAR_DATA_ROOT if set, else "procedural"; or "data"
    texture_size_px: int = 2048  # square tile, repeated (wraps) over the whole plane
    metres_per_texel: float = 0.1
    target_length_m: float = 5.0
    target_width_m: float = 2.2
    target_speed_m_s: float = 5.0
    target_start_north_m: float = 30.0  # ahead of a vehicle 30 m up at home, looking north at -45 degrees
    target_start_east_m: float = 0.0
    target_start_heading_deg: float = 30.0
    straight_s: tuple[float, float] = (4.0, 9.0)  # duration range of straight segments
    turn_s: tuple[float, float] = (2.0, 5.0)  # duration range of turns
    turn_rate_deg_s: tuple[float, float] = (12.0, 30.0)  # |heading rate| range of turns
    occlusion_times_s: tuple[float, ...] = (8.0,)  # the car is under an occluder's centre at these times
    occlusion_period_s: float = 25.0  # then one every period after the last listed time (0: none)
    occluder_kinds: tuple[str, ...] = ("canopy", "bridge")  # cycled over the occlusion times
    canopy_radius_m: float = 3.2
    bridge_width_m: float = 6.0  # along the road
    path_step_s: float = 0.02
    car_colour_bgr: tuple[int, int, int] | None = (40, 40, 200)  # None: drawn from the seed

    def __post_init__(self) -> None:
        if self.texture not in ("auto", "data", "procedural"):
            raise ValueError(f"texture must be auto, data or procedural, got {self.texture!r}")
        if self.texture_size_px < 256:
            raise ValueError(f"texture_size_px must be >= 256, got {self.texture_size_px}")
        if not self.occluder_kinds or any(k not in ("bridge", "canopy") for k in self.occluder_kinds):
            raise ValueError(f"occluder_kinds must be a non-empty sequence of bridge / canopy, got {self.occluder_kinds}")
        for name in ("metres_per_texel", "target_length_m", "target_width_m", "target_speed_m_s",
                     "canopy_radius_m", "bridge_width_m", "path_step_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class CameraPose:
    """Camera position (NED metres, altitude above ground) and earth-frame yaw / pitch in radians."""

    north: float
    east: float
    altitude: float
    yaw: float
    pitch: float


@dataclass(frozen=True)
class TargetPose:
    """Car centre (NED metres on the ground), heading (radians clockwise from north), speed (m/s)."""

    north: float
    east: float
    heading: float
    speed: float


@dataclass(frozen=True)
class Occluder:
    """A convex ground-plane polygon (N x 2 array of (north, east) metres) drawn over the car."""

    kind: str  # "canopy" or "bridge"
    polygon_ne: np.ndarray
    time_s: float  # when the car passes under its centre


@dataclass(frozen=True)
class GroundTruth:
    """The car in one frame: box (x, y, w, h) pixels of its projected outline (not clipped to the
    image), the fraction of its area inside the image and not occluded, its pose on the ground (None
    where unknown: a recorded sequence), and the derived flags."""

    box: tuple[float, float, float, float]
    in_view_fraction: float
    visible_fraction: float
    target: TargetPose | None

    @property
    def visible(self) -> bool:
        """At least half of the car can be seen."""
        return self.visible_fraction >= 0.5

    @property
    def centre(self) -> tuple[float, float]:
        """Box centre in pixels."""
        x, y, w, h = self.box
        return x + w / 2.0, y + h / 2.0


# ----- geometry (pure) ----------------------------------------------------------------------------
def camera_matrix(camera: CameraConfig) -> np.ndarray:
    """3x3 intrinsics K (pixels), principal point at the image centre."""
    f = camera.focal_px
    return np.array([[f, 0.0, camera.width / 2.0], [0.0, f, camera.height / 2.0], [0.0, 0.0, 1.0]])


def world_to_camera_rotation(yaw: float, pitch: float) -> np.ndarray:
    """3x3 R mapping NED vectors to camera axes (x right, y down, z forward); yaw/pitch in radians."""
    forward = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), -math.sin(pitch)])
    right = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    down = np.cross(forward, right)
    return np.stack([right, down, forward])


def ground_homography(camera: CameraConfig, pose: CameraPose) -> np.ndarray:
    """3x3 H with [u, v, w]^T = H [north, east, 1]^T for points on the ground plane."""
    rotation = world_to_camera_rotation(pose.yaw, pose.pitch)
    centre = np.array([pose.north, pose.east, -pose.altitude])
    return camera_matrix(camera) @ np.column_stack([rotation[:, 0], rotation[:, 1], -rotation @ centre])


def project_ground(h: np.ndarray, points_ne: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project N x 2 ground points; returns N x 2 pixels and an N bool mask 'in front of the camera'."""
    homog = np.column_stack([points_ne, np.ones(len(points_ne))]) @ h.T
    depth = homog[:, 2]
    safe = np.where(np.abs(depth) < 1e-9, 1e-9, depth)
    return homog[:, :2] / safe[:, None], depth > 1e-6


def horizon_row(camera: CameraConfig, pose: CameraPose) -> float:
    """Image row (pixels, may be outside the image) below which rays hit the ground."""
    rotation = world_to_camera_rotation(pose.yaw, pose.pitch)
    # A pixel's ray in NED has down component R[1,2]*(v-cy)/f + R[2,2] (R[0,2] = 0: no roll).
    d_row, f_row = rotation[1, 2], rotation[2, 2]
    if abs(d_row) < 1e-9:
        return -math.inf if f_row > 0 else math.inf
    return camera.height / 2.0 - f_row * camera.focal_px / d_row


def rectangle_ne(centre_n: float, centre_e: float, heading: float, length: float, width: float) -> np.ndarray:
    """4 x 2 corners (north, east) of a rectangle: front-left, front-right, rear-right, rear-left."""
    c, s = math.cos(heading), math.sin(heading)
    fwd, right = np.array([c, s]), np.array([-s, c])
    half_l, half_w = length / 2.0, width / 2.0
    centre = np.array([centre_n, centre_e])
    return np.stack([centre + fwd * half_l - right * half_w, centre + fwd * half_l + right * half_w,
                     centre - fwd * half_l + right * half_w, centre - fwd * half_l - right * half_w])


def convex_area(polygon: np.ndarray) -> float:
    """Area of a polygon (N x 2, any orientation) by the shoelace formula."""
    if len(polygon) < 3:
        return 0.0
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def convex_intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection polygon (M x 2) of two convex polygons (empty array when disjoint)."""
    area, poly = cv2.intersectConvexConvex(a.astype(np.float32), b.astype(np.float32))
    if poly is None or area <= 0:
        return np.zeros((0, 2))
    return poly.reshape(-1, 2).astype(np.float64)


# ----- target path (pure, deterministic) ----------------------------------------------------------
@dataclass
class TargetPath:
    """The car's route: straight segments and turns drawn from the seed, integrated at path_step_s and
    extended on demand (a one-hour soak only grows it to ~180k samples)."""

    config: SceneConfig
    times: list[float] = field(default_factory=list)
    samples: list[tuple[float, float, float]] = field(default_factory=list)  # (north, east, heading)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.config.seed)
        cfg = self.config
        self._state = (cfg.target_start_north_m, cfg.target_start_east_m, math.radians(cfg.target_start_heading_deg))
        self._segment_end = 0.0
        self._heading_rate = 0.0
        self._straight_next = True
        self.times.append(0.0)
        self.samples.append(self._state)

    def _next_segment(self) -> None:
        cfg, rng = self.config, self._rng
        if self._straight_next:
            duration, rate = rng.uniform(*cfg.straight_s), 0.0
        else:
            duration = rng.uniform(*cfg.turn_s)
            rate = math.radians(rng.uniform(*cfg.turn_rate_deg_s)) * rng.choice([-1.0, 1.0])
        self._straight_next = not self._straight_next
        self._segment_end += duration
        self._heading_rate = rate

    def _extend_to(self, t: float) -> None:
        cfg, dt = self.config, self.config.path_step_s
        while self.times[-1] < t + dt:
            now = self.times[-1]
            if now >= self._segment_end:
                self._next_segment()
            n, e, heading = self._state
            heading = heading + self._heading_rate * dt
            n += cfg.target_speed_m_s * math.cos(heading) * dt
            e += cfg.target_speed_m_s * math.sin(heading) * dt
            self._state = (n, e, heading)
            self.times.append(now + dt)
            self.samples.append(self._state)

    def pose(self, t: float) -> TargetPose:
        """Car pose at time t seconds (linear interpolation between integration steps)."""
        if t < 0:
            raise ValueError(f"time must be >= 0, got {t}")
        self._extend_to(t)
        index = min(int(t / self.config.path_step_s), len(self.times) - 2)
        frac = (t - self.times[index]) / self.config.path_step_s
        (n0, e0, h0), (n1, e1, h1) = self.samples[index], self.samples[index + 1]
        return TargetPose(n0 + (n1 - n0) * frac, e0 + (e1 - e0) * frac, h0 + (h1 - h0) * frac,
                          self.config.target_speed_m_s)


def occlusion_times(config: SceneConfig, until_s: float) -> list[float]:
    """Times at which the car passes under an occluder, up to until_s seconds."""
    times = [t for t in config.occlusion_times_s if t <= until_s]
    if config.occlusion_period_s > 0:
        t = (max(config.occlusion_times_s) if config.occlusion_times_s else 0.0) + config.occlusion_period_s
        while t <= until_s:
            times.append(t)
            t += config.occlusion_period_s
    return sorted(times)


def make_occluder(config: SceneConfig, pose: TargetPose, index: int, time_s: float) -> Occluder:
    """The index-th occluder (kinds cycled from config.occluder_kinds) centred on the route at `pose`."""
    if config.occluder_kinds[index % len(config.occluder_kinds)] == "canopy":
        angles = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
        r = config.canopy_radius_m
        polygon = np.column_stack([pose.north + r * np.cos(angles), pose.east + r * np.sin(angles)])
        return Occluder("canopy", polygon, time_s)
    # A bridge deck crossing the road at right angles: long across, bridge_width_m along the road.
    polygon = rectangle_ne(pose.north, pose.east, pose.heading, config.bridge_width_m, 40.0)
    return Occluder("bridge", polygon, time_s)


# ----- textures -----------------------------------------------------------------------------------
def procedural_ground(size: int, seed: int) -> np.ndarray:
    """size x size BGR uint8 ground tile made in code: fields, noise at several scales, roads (wraps)."""
    rng = np.random.default_rng(seed)
    image = np.zeros((size, size, 3), np.float32)
    palette = np.array([[60, 110, 80], [50, 90, 110], [70, 130, 120], [90, 110, 140], [40, 80, 60]], np.float32)
    cells = 6
    labels = rng.integers(0, len(palette), (cells, cells))
    fields = palette[labels]
    image += cv2.resize(fields, (size, size), interpolation=cv2.INTER_NEAREST)
    for scale, amplitude in ((8, 30.0), (32, 18.0), (128, 12.0), (512, 8.0)):
        noise = rng.standard_normal((scale, scale)).astype(np.float32)
        noise = cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)
        image += amplitude * noise[:, :, None]
    for _ in range(4):  # straight roads across the tile, wrapping
        vertical = rng.random() < 0.5
        pos = int(rng.integers(0, size))
        width = int(rng.integers(40, 80))
        sl = (slice(None), slice(pos, pos + width)) if vertical else (slice(pos, pos + width), slice(None))
        image[sl] = image[sl] * 0.3 + np.float32(95.0)
    return np.clip(image, 0, 255).astype(np.uint8)


def data_frames(data_root: Path) -> list[Path]:
    """Every frame path of every OTB-style sequence under data_root, in sorted order."""
    return sorted(data_root.glob("*/img/*.jpg"))


def ground_from_frames(frames: list[Path], size: int, seed: int, tiles: int = 8) -> np.ndarray:
    """size x size BGR ground tile mosaicked from real aerial frames (random crops, feathered seams)."""
    if not frames:
        raise ValueError("no frames to build a ground texture from")
    rng = np.random.default_rng(seed)
    cell = size // tiles
    image = np.zeros((size, size, 3), np.uint8)
    for row in range(tiles):
        for col in range(tiles):
            frame = cv2.imread(str(frames[int(rng.integers(0, len(frames)))]), cv2.IMREAD_COLOR)
            if frame is None:
                raise ValueError("unreadable frame while building the ground texture")
            h, w = frame.shape[:2]
            # 1-2 source pixels per texel: aerial frames have a few cm per pixel, texels are 10 cm.
            side = min(int(cell * rng.uniform(1.0, 2.0)), h, w)
            y0, x0 = int(rng.integers(0, h - side + 1)), int(rng.integers(0, w - side + 1))
            patch = cv2.resize(frame[y0:y0 + side, x0:x0 + side], (cell, cell), interpolation=cv2.INTER_AREA)
            image[row * cell:(row + 1) * cell, col * cell:(col + 1) * cell] = patch
    # Soften the seams so tile edges do not form a strong grid the tracker could latch on to.
    blurred = cv2.GaussianBlur(image, (0, 0), 6)
    seam = np.zeros((size, size), np.float32)
    for k in range(tiles + 1):
        seam[:, min(k * cell, size - 1)] = 1.0
        seam[min(k * cell, size - 1), :] = 1.0
    seam = cv2.GaussianBlur(seam, (0, 0), 8)
    seam = np.clip(seam / max(seam.max(), 1e-6) * 2.0, 0.0, 1.0)[:, :, None]
    return (image * (1.0 - seam) + blurred * seam).astype(np.uint8)


def car_texture(seed: int, colour_bgr: tuple[int, int, int] | None = None, length_px: int = 100,
                width_px: int = 44) -> np.ndarray:
    """Top view of a car (BGR uint8, x = forward): coloured body (given, or drawn from the seed), dark
    windows, light roof."""
    rng = np.random.default_rng(seed + 1)
    palette = [[40, 40, 200], [200, 200, 210], [30, 160, 230], [180, 60, 40]]
    body = np.array(colour_bgr if colour_bgr is not None else palette[int(rng.integers(0, len(palette)))], np.uint8)
    tex = np.empty((width_px, length_px, 3), np.uint8)
    tex[:] = body
    # Windscreen (front), rear window, roof panel: give the car inner structure to correlate on.
    cv2.rectangle(tex, (int(length_px * 0.58), 4), (int(length_px * 0.72), width_px - 5), (35, 30, 30), -1)
    cv2.rectangle(tex, (int(length_px * 0.18), 5), (int(length_px * 0.27), width_px - 6), (35, 30, 30), -1)
    roof = np.clip(body.astype(int) + 40, 0, 255).astype(np.uint8)
    cv2.rectangle(tex, (int(length_px * 0.28), 7), (int(length_px * 0.57), width_px - 8), roof.tolist(), -1)
    cv2.rectangle(tex, (0, 0), (length_px - 1, width_px - 1), (20, 20, 20), 2)
    return tex


def canopy_texture(seed: int, size: int = 96) -> np.ndarray:
    """Top view of a tree canopy (BGR uint8): leafy greens with shading."""
    rng = np.random.default_rng(seed + 2)
    noise = sum(cv2.resize(rng.standard_normal((s, s)).astype(np.float32), (size, size),
                           interpolation=cv2.INTER_CUBIC) * a for s, a in ((6, 25.0), (24, 20.0), (96, 10.0)))
    base = np.array([40, 100, 45], np.float32)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    shade = 1.0 - 0.35 * np.hypot(xx - size * 0.4, yy - size * 0.4) / size
    return np.clip((base + noise[:, :, None]) * shade[:, :, None], 0, 255).astype(np.uint8)


def bridge_texture(length_px: int = 48, width_px: int = 320) -> np.ndarray:
    """Top view of a bridge deck (BGR uint8, x along the road below, y across): asphalt and rails."""
    tex = np.full((width_px, length_px, 3), 105, np.uint8)
    cv2.rectangle(tex, (0, 0), (5, width_px - 1), (190, 190, 190), -1)
    cv2.rectangle(tex, (length_px - 6, 0), (length_px - 1, width_px - 1), (190, 190, 190), -1)
    for y in range(0, width_px, 24):  # lane dashes along the deck
        cv2.line(tex, (length_px // 2, y), (length_px // 2, y + 10), (220, 220, 220), 2)
    return tex


def load_ground_texture(config: SceneConfig) -> tuple[np.ndarray, str]:
    """The ground tile and where it came from ("data: N frames" or "procedural")."""
    root = os.environ.get("JSAR_DATA_ROOT", "")
    if config.texture in ("auto", "data") and root and Path(root).is_dir():
        frames = data_frames(Path(root))
        if frames:
            return ground_from_frames(frames, config.texture_size_px, config.seed), f"data: {len(frames)} frames"
    if config.texture == "data":
        raise ValueError("texture 'data' needs JSAR_DATA_ROOT pointing at OTB-style sequences")
    return procedural_ground(config.texture_size_px, config.seed), "procedural"


# ----- rendering ----------------------------------------------------------------------------------
def texture_to_ground(texture_shape: tuple[int, ...], corners_ne: np.ndarray) -> np.ndarray:
    """3x3 affine mapping texture pixels (x along corner 3->0 'forward', y along 0->1 'right') to ground."""
    h, w = texture_shape[:2]
    src = np.float32([[w, 0], [w, h], [0, h]])
    return np.vstack([cv2.getAffineTransform(src, corners_ne[:3].astype(np.float32)), [0.0, 0.0, 1.0]])


def paste_on_ground(image: np.ndarray, h_ground: np.ndarray, texture: np.ndarray, corners_ne: np.ndarray,
                    clip_ne: np.ndarray | None = None) -> None:
    """Draw `texture` mapped onto the ground quad `corners_ne` into `image` (in place), optionally
    masked to the ground polygon `clip_ne` (e.g. a round canopy inside its square texture)."""
    pixels, in_front = project_ground(h_ground, corners_ne)
    if not in_front.all():
        return  # partly behind the camera: never the case for the near-nadir views we render
    height, width = image.shape[:2]
    x0, y0 = np.floor(pixels.min(axis=0)).astype(int)
    x1, y1 = np.ceil(pixels.max(axis=0)).astype(int)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
    if x1 <= x0 or y1 <= y0:
        return
    shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
    h_tex = shift @ h_ground @ texture_to_ground(texture.shape, corners_ne)
    size = (x1 - x0, y1 - y0)
    warped = cv2.warpPerspective(texture, h_tex, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    outline = clip_ne if clip_ne is not None else corners_ne
    outline_px, _ = project_ground(shift @ h_ground, outline)
    cv2.fillConvexPoly(mask, np.round(outline_px * 16).astype(np.int32), 255, cv2.LINE_AA, shift=4)
    roi = image[y0:y1, x0:x1]
    alpha = (mask.astype(np.float32) / 255.0)[:, :, None]
    roi[:] = (warped * alpha + roi * (1.0 - alpha)).astype(np.uint8)


class Scene:
    """Renders frames and ground truth for a camera pose at a time; deterministic given the config."""

    def __init__(self, config: SceneConfig = SceneConfig(), camera: CameraConfig = CameraConfig(),
                 ground: np.ndarray | None = None) -> None:
        self.config = config
        self.camera = camera
        if ground is None:
            ground, self.texture_source = load_ground_texture(config)
        else:
            self.texture_source = "given"
        self.ground = ground
        self.path = TargetPath(config)
        self.car = car_texture(config.seed, config.car_colour_bgr)
        self.canopy = canopy_texture(config.seed)
        self.bridge = bridge_texture()
        self._occluders: list[Occluder] = []
        self._occluders_until = -1.0
        m = config.metres_per_texel
        # Ground (north, east) -> texel (x = east / m, y = -north / m), offset so home is mid-tile.
        half = config.texture_size_px / 2.0
        self._ground_from_texel = np.linalg.inv(np.array([[0.0, 1.0 / m, half], [-1.0 / m, 0.0, half],
                                                          [0.0, 0.0, 1.0]]))

    def occluders(self, until_s: float) -> list[Occluder]:
        """Occluders placed on the route up to until_s seconds (created on demand, then kept)."""
        if until_s > self._occluders_until:
            horizon = until_s + 30.0  # place ahead so an occluder is on screen before the car reaches it
            times = occlusion_times(self.config, horizon)
            self._occluders = [make_occluder(self.config, self.path.pose(t), i, t) for i, t in enumerate(times)]
            self._occluders_until = horizon
        return self._occluders

    def ground_truth(self, pose: CameraPose, t: float) -> GroundTruth:
        """The car's box and visibility for a camera pose at time t (no rendering)."""
        target = self.path.pose(t)
        h = ground_homography(self.camera, pose)
        corners = rectangle_ne(target.north, target.east, target.heading, self.config.target_length_m,
                               self.config.target_width_m)
        pixels, in_front = project_ground(h, corners)
        if not in_front.all():
            return GroundTruth((math.nan,) * 4, 0.0, 0.0, target)
        x0, y0 = pixels.min(axis=0)
        x1, y1 = pixels.max(axis=0)
        area = convex_area(pixels)
        frame = np.array([[0, 0], [self.camera.width, 0], [self.camera.width, self.camera.height],
                          [0, self.camera.height]], np.float64)
        inside = convex_intersection(pixels, frame)
        inside_area = convex_area(inside)
        hidden = 0.0
        if inside_area > 0:
            for occ in self._nearby_occluders(target, t):
                occ_px, occ_front = project_ground(h, occ.polygon_ne)
                if occ_front.all():
                    hidden += convex_area(convex_intersection(inside, occ_px))
        in_view = inside_area / area if area > 0 else 0.0
        visible = max(inside_area - hidden, 0.0) / area if area > 0 else 0.0
        return GroundTruth((float(x0), float(y0), float(x1 - x0), float(y1 - y0)), in_view, visible, target)

    def _nearby_occluders(self, target: TargetPose, t: float) -> list[Occluder]:
        reach = 30.0  # metres: only occluders that can overlap the car (bridges are 40 m long)
        return [o for o in self.occluders(t)
                if np.min(np.hypot(o.polygon_ne[:, 0] - target.north, o.polygon_ne[:, 1] - target.east)) < reach]

    def render(self, pose: CameraPose, t: float) -> tuple[np.ndarray, GroundTruth]:
        """BGR uint8 frame (camera.height x camera.width x 3) and the ground truth at time t."""
        cam = self.camera
        h = ground_homography(cam, pose)
        h_texel = h @ self._ground_from_texel
        frame = cv2.warpPerspective(self.ground, h_texel, (cam.width, cam.height), flags=cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_WRAP)
        horizon = horizon_row(cam, pose)
        if horizon > 0:  # sky above the horizon (the warp there shows the plane 'behind' the camera)
            rows = int(min(math.ceil(horizon), cam.height))
            frame[:rows] = (200, 170, 140)
        target = self.path.pose(t)
        corners = rectangle_ne(target.north, target.east, target.heading, self.config.target_length_m,
                               self.config.target_width_m)
        paste_on_ground(frame, h, self.car, corners)
        for occ in self._nearby_occluders(target, t) + self._visible_far_occluders(t, pose):
            if occ.kind == "canopy":
                centre = occ.polygon_ne.mean(axis=0)
                r = float(np.max(np.hypot(*(occ.polygon_ne - centre).T)))
                square = rectangle_ne(centre[0], centre[1], 0.0, 2 * r, 2 * r)
                paste_on_ground(frame, h, self.canopy, square, clip_ne=occ.polygon_ne)
            else:
                paste_on_ground(frame, h, self.bridge, occ.polygon_ne)
        return frame, self.ground_truth(pose, t)

    def _visible_far_occluders(self, t: float, pose: CameraPose) -> list[Occluder]:
        """Occluders further from the car but within 150 m of the camera (drawn so they exist before and
        after the car passes: an occluder that only appeared around the car would give it away)."""
        target = self.path.pose(t)
        near = {id(o) for o in self._nearby_occluders(target, t)}
        return [o for o in self.occluders(t) if id(o) not in near and
                math.hypot(o.polygon_ne[0, 0] - pose.north, o.polygon_ne[0, 1] - pose.east) < 150.0]


def pose_from_vehicle(north: float, east: float, down: float, vehicle_yaw: float, gimbal_pitch: float,
                      gimbal_yaw: float) -> CameraPose:
    """Camera pose from the vehicle's NED position, yaw and the gimbal's earth-frame pitch and
    vehicle-frame yaw (radians), as `sim.vehicle_model.VehicleState` holds them."""
    return CameraPose(north, east, -down, vehicle_yaw + gimbal_yaw, gimbal_pitch)
