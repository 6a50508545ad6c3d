"""The twin's cameras: front (forward, tilted up) and bottom (straight down), rendered from
the true pose with plain numpy/OpenCV, no GPU.

The ground is a plane, so a pinhole camera sees it through a homography: one
`warpPerspective` of a ground texture per frame, plus finer textures warped over the pads
(markers readable from 4 m in the bottom view). Sky fills the half-plane above the
horizon line. Obstacles are boxes drawn after the ground, far to near, with back faces
culled and polygons clipped at the near plane, so they occlude correctly. The boundary
net is drawn as poles and ropes. Optional analog-FPV look: blur, noise, tearing lines.

Camera frame: OpenCV's (x right, y down, z forward). Body frame FLU, world ENU.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from fpv_station.core.scene import Pad, Scene
from fpv_station.twin.sim import Pose

SKY_BGR = (235, 200, 150)
NEAR_M = 0.05


@dataclass(frozen=True)
class CameraModel:
    name: str
    R_body_cam: np.ndarray  # columns: camera x, y, z axes in body FLU
    offset_body_m: np.ndarray
    hfov_deg: float = 100.0
    width: int = 640
    height: int = 480

    @property
    def K(self) -> np.ndarray:
        f = (self.width / 2) / np.tan(np.radians(self.hfov_deg) / 2)
        return np.array([[f, 0, self.width / 2], [0, f, self.height / 2], [0, 0, 1.0]])

    @property
    def vfov_deg(self) -> float:
        """Top edge to bottom edge of the frame, through K's square pixels."""
        return float(np.degrees(2 * np.arctan((self.height / 2) / self.K[1, 1])))

    @property
    def tilt_up_deg(self) -> float:
        """The optical axis above the body's nose (FLU: its up component)."""
        return float(np.degrees(np.arcsin(np.clip(self.R_body_cam[2, 2], -1.0, 1.0))))


def front_camera(tilt_up_deg: float = 15.0, hfov_deg: float = 100.0) -> CameraModel:
    t = np.radians(tilt_up_deg)
    z = np.array([np.cos(t), 0.0, np.sin(t)])
    x = np.array([0.0, -1.0, 0.0])
    # Offsets are from the body origin at the skids' bottom (pose z = 0 on the ground):
    # an F450 on its landing gear carries the cameras ~10-20 cm above the grass.
    return CameraModel(
        "front", np.column_stack([x, np.cross(z, x), z]), np.array([0.10, 0.0, 0.20]), hfov_deg
    )


def bottom_camera(hfov_deg: float = 90.0) -> CameraModel:
    x, y, z = np.array([0.0, -1.0, 0.0]), np.array([-1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0])
    return CameraModel("bottom", np.column_stack([x, y, z]), np.array([0.0, 0.0, 0.12]), hfov_deg)


def camera_pose(cam: CameraModel, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """(R_world_cam, t_world_cam); the camera never goes below 3 cm (skids on the grass)."""
    R_wc = pose.R_world_body @ cam.R_body_cam
    t_wc = pose.pos_enu_m + pose.R_world_body @ cam.offset_body_m
    t_wc = t_wc.copy()
    t_wc[2] = max(t_wc[2], 0.03)
    return R_wc, t_wc


def project(
    cam: CameraModel, pose: Pose, points_world: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (K, 2) of world points (K, 3) and their depth along the optical axis (K,)."""
    R_wc, t_wc = camera_pose(cam, pose)
    pc = (np.asarray(points_world, float) - t_wc) @ R_wc
    uv = pc @ cam.K.T
    return uv[:, :2] / uv[:, 2:3], pc[:, 2]


class Renderer:
    def __init__(
        self,
        scene: Scene,
        fpv_noise: bool = False,
        seed: int = 0,
        front: CameraModel | None = None,
        bottom: CameraModel | None = None,
        margin_m: float = 25.0,
        pad_px_per_m: int = 160,
    ) -> None:
        self.scene = scene
        self.cameras = self.camera_models(front, bottom)
        self.fpv_noise = fpv_noise
        self._rng = np.random.default_rng(seed)
        f = scene.field
        self.ppm = f.texture_px_per_m
        self.x0 = -f.size_x_m / 2 - margin_m
        self.y1 = f.size_y_m / 2 + margin_m
        self.ground = self._ground_texture(f.size_x_m + 2 * margin_m, f.size_y_m + 2 * margin_m)
        self.A_world_tex = np.array(
            [[1 / self.ppm, 0, self.x0], [0, -1 / self.ppm, self.y1], [0, 0, 1.0]]
        )
        self.pad_ppm = pad_px_per_m
        self.pads = [(pad, self._pad_texture(pad, pad_px_per_m)) for pad in scene.pads]
        for pad, tex in self.pads:  # coarse copy in the ground for distant views
            self._stamp(pad, tex)
        self._noise = [self._rng.normal(0, 12, (480, 640, 3)).astype(np.int16) for _ in range(6)]
        self._net = self._net_segments()

    @staticmethod
    def camera_models(
        front: CameraModel | None = None, bottom: CameraModel | None = None
    ) -> dict[str, CameraModel]:
        """The cameras a renderer built with these options draws (cheap: no textures)."""
        return {"front": front or front_camera(), "bottom": bottom or bottom_camera()}

    # ---- textures ----
    def _ground_texture(self, w_m: float, h_m: float) -> np.ndarray:
        f, ppm = self.scene.field, self.ppm
        w, h = int(w_m * ppm), int(h_m * ppm)
        rng = np.random.default_rng(12345)
        tex = np.empty((h, w, 3), np.uint8)
        tex[:] = f.outside_bgr
        fx0 = int((-f.size_x_m / 2 - self.x0) * ppm)
        fy0 = int((self.y1 - f.size_y_m / 2) * ppm)
        fw, fh = int(f.size_x_m * ppm), int(f.size_y_m * ppm)
        field = tex[fy0 : fy0 + fh, fx0 : fx0 + fw]
        field[:] = f.grass_bgr
        stripe = int(5 * ppm)  # mowing stripes, 5 m wide: cues for speed and heading
        for x in range(0, fw, 2 * stripe):
            field[:, x : x + stripe] = np.clip(np.array(f.grass_bgr) * 1.12, 0, 255).astype(
                np.uint8
            )
        coarse = rng.normal(0, 1, (h // 4 + 1, w // 4 + 1)).astype(np.float32)
        noise = cv2.resize(cv2.GaussianBlur(coarse, (0, 0), 1.5), (w, h))[..., None]
        fine = rng.normal(0, 7, (h, w, 1)).astype(np.float32)
        tex = np.clip(tex.astype(np.float32) + 14 * noise + fine, 0, 255).astype(np.uint8)
        cv2.rectangle(tex, (fx0, fy0), (fx0 + fw, fy0 + fh), (235, 235, 235), max(2, ppm // 8))
        cv2.line(
            tex, (fx0 + fw // 2, fy0), (fx0 + fw // 2, fy0 + fh), (210, 210, 210), max(1, ppm // 10)
        )
        return tex

    @staticmethod
    def _pad_texture(pad: Pad, ppm: int) -> np.ndarray:
        n = int(pad.size_m * ppm)
        tex = np.empty((n, n, 3), np.uint8)
        tex[:] = pad.bgr
        c, col = n // 2, tuple(int(v) for v in pad.marker_bgr)
        cv2.circle(tex, (c, c), int(n * 0.42), col, max(2, n // 30), cv2.LINE_AA)
        t = max(3, n // 10)
        if pad.marker.upper() == "X":
            d = int(n * 0.25)
            cv2.line(tex, (c - d, c - d), (c + d, c + d), col, t, cv2.LINE_AA)
            cv2.line(tex, (c - d, c + d), (c + d, c - d), col, t, cv2.LINE_AA)
        else:  # "H" and anything else: the helipad H
            a, b = int(n * 0.2), int(n * 0.25)
            cv2.rectangle(tex, (c - a - t // 2, c - b), (c - a + t // 2, c + b), col, -1)
            cv2.rectangle(tex, (c + a - t // 2, c - b), (c + a + t // 2, c + b), col, -1)
            cv2.rectangle(tex, (c - a, c - t // 2), (c + a, c + t // 2), col, -1)
        return tex

    def _A_world_pad(self, pad: Pad) -> np.ndarray:
        """Pad texture pixel (u, v) -> world (x, y, 1). The texture's up points east, so a
        vehicle on the field's heading (east) sees its marker upright in the bottom view."""
        s = 1.0 / self.pad_ppm
        half = pad.size_m / 2
        return np.array([[0, -s, pad.x_m + half], [-s, 0, pad.y_m + half], [0, 0, 1.0]])

    def _stamp(self, pad: Pad, tex: np.ndarray) -> None:
        n = int(pad.size_m * self.ppm)
        u0 = int(round((pad.x_m - pad.size_m / 2 - self.x0) * self.ppm))
        v0 = int(round((self.y1 - pad.y_m - pad.size_m / 2) * self.ppm))
        east_right = cv2.rotate(tex, cv2.ROTATE_90_CLOCKWISE)  # ground texture: up = north
        self.ground[v0 : v0 + n, u0 : u0 + n] = cv2.resize(
            east_right, (n, n), interpolation=cv2.INTER_AREA
        )

    def _net_segments(self) -> np.ndarray:
        f = self.scene.field
        hx, hy, top = f.size_x_m / 2, f.size_y_m / 2, f.net_height_m
        if top <= 0:
            return np.zeros((0, 2, 3))
        corners = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy)]
        segs = []
        for (xa, ya), (xb, yb) in zip(corners[:-1], corners[1:]):
            length = np.hypot(xb - xa, yb - ya)
            for s in np.linspace(0, 1, int(length // 5) + 1, endpoint=False):
                x, y = xa + s * (xb - xa), ya + s * (yb - ya)
                segs.append([(x, y, 0.0), (x, y, top)])
            for z in (top, top / 2, 0.3):
                segs.append([(xa, ya, z), (xb, yb, z)])
        return np.array(segs)

    # ---- rendering ----
    def render(self, camera: str, pose: Pose) -> np.ndarray:
        cam = self.cameras.get(camera)
        if cam is None:
            raise ValueError(f"Unknown camera '{camera}'; the twin has 'front' and 'bottom'.")
        R_wc, t_wc = camera_pose(cam, pose)
        R_cw = R_wc.T
        t_cw = -R_cw @ t_wc
        K, W, H = cam.K, cam.width, cam.height
        G = K @ np.column_stack([R_cw[:, 0], R_cw[:, 1], t_cw])  # world ground (x, y, 1) -> px
        frame = cv2.warpPerspective(
            self.ground,
            G @ self.A_world_tex,
            (W, H),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=self.scene.field.outside_bgr,
        )
        for pad, tex in self.pads:
            self._draw_pad(frame, cam, G, R_cw, t_cw, pad, tex)
        self._draw_sky(frame, K, R_wc)
        self._draw_net(frame, K, R_cw, t_cw)
        self._draw_obstacles(frame, K, R_cw, t_cw, t_wc)
        if self.fpv_noise:
            frame = self._analog(frame)
        return frame

    def _draw_pad(self, frame, cam, G, R_cw, t_cw, pad: Pad, tex) -> None:
        half = pad.size_m / 2
        corners = np.array(
            [[pad.x_m + dx, pad.y_m + dy, 0.0] for dx in (-half, half) for dy in (-half, half)]
        )
        pc = corners @ R_cw.T + t_cw
        if (pc[:, 2] < NEAR_M).any():
            return  # partly behind the camera: the ground texture's coarse copy shows it
        uv = pc[:, :2] / pc[:, 2:3]
        uv = uv @ cam.K[:2, :2].T + cam.K[:2, 2]
        u0, v0 = np.floor(uv.min(axis=0)).astype(int)
        u1, v1 = np.ceil(uv.max(axis=0)).astype(int) + 1
        u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, cam.width), min(v1, cam.height)
        if u1 - u0 < 8 or v1 - v0 < 8:
            return  # too small to need more detail than the ground texture has
        T = np.array([[1, 0, -u0], [0, 1, -v0], [0, 0, 1.0]])
        roi = frame[v0:v1, u0:u1]
        cv2.warpPerspective(
            tex,
            T @ G @ self._A_world_pad(pad),
            (u1 - u0, v1 - v0),
            dst=roi,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_TRANSPARENT,
        )

    @staticmethod
    def _draw_sky(frame, K, R_wc) -> None:
        # Pixels whose ray points up (d_z >= 0) see sky: a half-plane a u + b v + c >= 0.
        a, b, c = (R_wc @ np.linalg.inv(K))[2]
        H, W = frame.shape[:2]
        poly = _clip_polygon(
            np.array([[0, 0], [W, 0], [W, H], [0, H]], float),
            lambda p: a * p[:, 0] + b * p[:, 1] + c,
        )
        if len(poly) >= 3:
            cv2.fillPoly(frame, [np.round(poly).astype(np.int32)], SKY_BGR, cv2.LINE_AA)

    def _draw_net(self, frame, K, R_cw, t_cw) -> None:
        if not len(self._net):
            return
        pc = self._net @ R_cw.T + t_cw  # (S, 2, 3)
        za, zb = pc[:, 0, 2], pc[:, 1, 2]
        keep = (za > NEAR_M) | (zb > NEAR_M)
        pc = pc[keep]
        za, zb = pc[:, 0, 2], pc[:, 1, 2]
        # Clip each segment at the near plane.
        s = np.clip((NEAR_M - za) / np.where(zb - za == 0, 1e-9, zb - za), 0, 1)[:, None]
        a = np.where((za < NEAR_M)[:, None], pc[:, 0] + s * (pc[:, 1] - pc[:, 0]), pc[:, 0])
        b = np.where((zb < NEAR_M)[:, None], pc[:, 0] + s * (pc[:, 1] - pc[:, 0]), pc[:, 1])
        pts = np.stack([a, b], axis=1) @ K.T
        px = pts[..., :2] / pts[..., 2:3]
        px = np.clip(px, -1e4, 1e4)
        cv2.polylines(
            frame, list(np.round(px).astype(np.int32)), False, (60, 60, 60), 1, cv2.LINE_AA
        )

    def _draw_obstacles(self, frame, K, R_cw, t_cw, t_wc) -> None:
        light = np.array([0.4, -0.3, 0.85])
        order = sorted(
            self.scene.obstacles, key=lambda o: -np.hypot(o.x_m - t_wc[0], o.y_m - t_wc[1])
        )
        for o in order:
            c = o.corners_m()
            faces = [
                (c[[4, 5, 6, 7]], (0, 0, 1)),
                (c[[0, 1, 5, 4]], (0, -1, 0)),
                (c[[1, 2, 6, 5]], (1, 0, 0)),
                (c[[2, 3, 7, 6]], (0, 1, 0)),
                (c[[3, 0, 4, 7]], (-1, 0, 0)),
            ]
            for quad, normal in faces:
                n = np.array(normal, float)
                if n @ (t_wc - quad.mean(axis=0)) <= 0:
                    continue  # back face
                pc = quad @ R_cw.T + t_cw
                pc = _clip_polygon(pc, lambda p: p[:, 2] - NEAR_M)
                if len(pc) < 3:
                    continue
                uv = pc @ K.T
                px = np.clip(uv[:, :2] / uv[:, 2:3], -1e4, 1e4)
                shade = 0.55 + 0.45 * max(float(n @ light), 0.0)
                color = tuple(int(v * shade) for v in o.bgr)
                cv2.fillConvexPoly(frame, np.round(px).astype(np.int32), color, cv2.LINE_AA)
                cv2.polylines(
                    frame,
                    [np.round(px).astype(np.int32)],
                    True,
                    tuple(int(v * 0.5) for v in o.bgr),
                    1,
                    cv2.LINE_AA,
                )

    def _analog(self, frame: np.ndarray) -> np.ndarray:
        """600 TVL analog look: soft, grainy, less saturated, the odd torn line."""
        out = cv2.GaussianBlur(frame, (3, 3), 0)
        noise = self._noise[int(self._rng.integers(len(self._noise)))]
        out = np.clip(out.astype(np.int16) + noise, 0, 255).astype(np.uint8)
        if self._rng.random() < 0.15:
            row = int(self._rng.integers(0, out.shape[0] - 3))
            out[row : row + 2] = np.roll(out[row : row + 2], int(self._rng.integers(5, 30)), axis=1)
        return out


def _clip_polygon(poly: np.ndarray, inside) -> np.ndarray:
    """Sutherland-Hodgman against one half-space `inside(points) >= 0` (any dimension)."""
    if not len(poly):
        return poly
    d = inside(poly)
    out = []
    n = len(poly)
    for i in range(n):
        p, q, dp, dq = poly[i], poly[(i + 1) % n], d[i], d[(i + 1) % n]
        if dp >= 0:
            out.append(p)
        if (dp >= 0) != (dq >= 0):
            out.append(p + (q - p) * (dp / (dp - dq)))
    return np.array(out) if out else np.zeros((0, poly.shape[1]))
