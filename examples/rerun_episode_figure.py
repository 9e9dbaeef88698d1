"""Draw one recorded pick episode (a `--rerun FILE.rrd` recording) as a still figure, from the recording.

The rerun viewer is the way to step through a recording; this script is for where no viewer runs (a headless
machine, a docs page). It reads the .rrd with rerun's own reader (extra `viz`) and draws with OpenCV:

    MUJOCO_GL=egl python -m sim pick --scene sim/scenes/tabletop_household.yaml \
        --command "pick up the green bottle" --out demo_out --seed 0 --rerun demo_out/episode.rrd
    python examples/rerun_episode_figure.py demo_out/episode.rrd docs/images/rerun_episode.jpg

Panels: the fixed camera's first and the wrist camera's last frame with the grounding candidates' boxes
(the recorded 2D boxes and labels; the best one green); the six joints measured (lines) and planned (dots)
over the episode's time line; the jaw width and the commanded force with the loop's stages; the TCP paths
planned (blue) and measured (green) over the observed scene points, from above and from the side (base
frame).
"""

from __future__ import annotations

import collections
import sys

import cv2
import numpy as np
from rerun.chunk import RrdReader

W, H = 640, 480
JOINT_COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75)]


def read(path: str) -> dict[str, list[tuple[float, dict]]]:
    """entity path -> [(episode time [s], {column: value})], in time order (static rows at t = -1)."""
    rows: dict[str, list[tuple[float, dict]]] = collections.defaultdict(list)
    for chunk in RrdReader(path).stream().to_chunks():
        table = chunk.to_record_batch().to_pylist()
        for row in table:
            t = row.get("episode")
            seconds = -1.0 if t is None else t.total_seconds()
            rows[chunk.entity_path].append((seconds, row))
    for entity in rows:
        rows[entity].sort(key=lambda r: r[0])
    return rows


def bgr(rgb):
    return tuple(int(c) for c in rgb[::-1])


def camera_panel(rows, camera: str, title: str, k: int = 0) -> np.ndarray:
    """The camera's k-th recorded frame (-1: the last) with the grounding boxes recorded on it."""
    base = f"/world/cameras/{camera}/image"
    if not rows.get(f"{base}/rgb"):
        return blank(title + " (not recorded)")
    _, row = rows[f"{base}/rgb"][k]
    image = cv2.imdecode(np.frombuffer(bytes(row["EncodedImage:blob"][0]), np.uint8), cv2.IMREAD_COLOR)
    sx, sy = W / image.shape[1], H / image.shape[0]  # the boxes are in the recorded image's pixels
    image = cv2.resize(image, (W, H))
    boxes = rows.get(f"{base}/grounding/boxes", [])
    if boxes:
        _, b = boxes[k]
        for k, (c, h, label) in enumerate(
            zip(b["Boxes2D:centers"], b["Boxes2D:half_sizes"], b["Boxes2D:labels"])
        ):
            colour = (60, 220, 90) if k == 0 else (200, 200, 200)
            p0 = (int(sx * (c[0] - h[0])), int(sy * (c[1] - h[1])))
            p1 = (int(sx * (c[0] + h[0])), int(sy * (c[1] + h[1])))
            cv2.rectangle(image, p0, p1, colour, 2 if k == 0 else 1)
            if k < 3:
                cv2.putText(
                    image, label, (p0[0], max(12, p0[1] - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1
                )
    put_title(image, title)
    return image


def blank(title: str) -> np.ndarray:
    image = np.full((H, W, 3), 255, np.uint8)
    put_title(image, title)
    return image


def put_title(image: np.ndarray, title: str) -> None:
    cv2.rectangle(image, (0, 0), (W, 22), (255, 255, 255), -1)
    cv2.putText(image, title, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)


class Axes:
    """A plot area in a panel: data (x, y) -> pixels, with ticks."""

    def __init__(self, image, x_range, y_range, x_label, y_label, box=(60, 35, W - 20, H - 45)):
        self.image, self.box = image, box
        (self.x0, self.x1), (self.y0, self.y1) = x_range, y_range
        l, t, r, b = box
        cv2.rectangle(image, (l, t), (r, b), (0, 0, 0), 1)
        for v in np.linspace(self.x0, self.x1, 6):
            x, _ = self.px(v, self.y0)
            cv2.putText(image, f"{v:.2g}", (x - 10, b + 16), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
        for v in np.linspace(self.y0, self.y1, 5):
            _, y = self.px(self.x0, v)
            cv2.putText(image, f"{v:.2g}", (4, y + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
        cv2.putText(image, x_label, ((l + r) // 2 - 40, H - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
        cv2.putText(image, y_label, (4, t - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)

    def px(self, x, y):
        l, t, r, b = self.box
        u = l + (np.asarray(x) - self.x0) / (self.x1 - self.x0) * (r - l)
        v = b - (np.asarray(y) - self.y0) / (self.y1 - self.y0) * (b - t)
        return np.round(u).astype(int), np.round(v).astype(int)

    def line(self, x, y, colour, thickness=1):
        u, v = self.px(x, y)
        cv2.polylines(
            self.image, [np.stack([u, v], 1).astype(np.int32)], False, colour, thickness, cv2.LINE_AA
        )

    def dots(self, x, y, colour, radius=2):
        for u, v in zip(*self.px(x, y)):
            cv2.circle(self.image, (int(u), int(v)), radius, colour, -1, cv2.LINE_AA)


def series(rows, entity: str) -> tuple[np.ndarray, np.ndarray]:
    data = [(t, r["Scalars:scalars"]) for t, r in rows.get(entity, []) if t >= 0 and r.get("Scalars:scalars")]
    if not data:
        return np.zeros(0), np.zeros((0, 1))
    return np.array([t for t, _ in data]), np.array([v for _, v in data], dtype=np.float64)


def joints_panel(rows, t_end: float) -> np.ndarray:
    image = blank("arm joints [rad]: measured (lines), planned (dots)")
    tm, qm = series(rows, "/arm/joints/measured")
    tp, qp = series(rows, "/arm/joints/planned")
    both = np.concatenate([qm.ravel(), qp.ravel()])
    ax = Axes(image, (0, t_end), (float(both.min()) - 0.1, float(both.max()) + 0.1), "episode time [s]", "")
    for j in range(6):
        colour = bgr(JOINT_COLOURS[j])
        if len(tm):
            ax.line(tm, qm[:, j], colour, 2)
        if len(tp):
            ax.dots(tp, qp[:, j], colour, 3)
    return image


def gripper_panel(rows, t_end: float) -> np.ndarray:
    image = blank("jaw width [cm] (green), commanded force / 10 [N] (red); the loop's stages")
    tw, w = series(rows, "/gripper/width_m")
    tf, f = series(rows, "/gripper/force_n")
    ax = Axes(image, (0, t_end), (0, 10), "episode time [s]", "")
    if len(tw):
        ax.line(tw, 100 * w[:, 0], (60, 170, 40), 2)
        ax.dots(tw, 100 * w[:, 0], (60, 170, 40), 2)
    if len(tf):
        # a command holds until the next one: drawn as steps
        ts = np.repeat(np.append(tf, t_end), 2)[1:-1]
        ax.line(ts, np.repeat(f[:, 0], 2) / 10.0, (40, 40, 220), 2)
    last_stage, y = None, 60
    for t, r in rows.get("/events", []):
        text = r["TextLog:text"][0]
        stage = text.split(":")[0]
        if stage != last_stage and t >= 0:
            u, _ = ax.px(t, 0)
            cv2.line(image, (int(u), 35), (int(u), H - 45), (190, 190, 190), 1)
            cv2.putText(image, stage, (int(u) + 2, y), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (90, 90, 90), 1)
            y = 60 if y > 150 else y + 18
        last_stage = stage
    return image


def paths_panel(rows, axes: tuple[int, int], title: str, labels: tuple[str, str]) -> np.ndarray:
    image = blank(title)
    target = rows["/world/target/box"][0][1]
    centre = np.array(target["Boxes3D:centers"][0])
    tcp = np.array([r["Transform3D:translation"][0] for t, r in rows.get("/world/arm/tcp", []) if t >= 0])
    seen = np.vstack([centre[None, :], tcp]) if len(tcp) else centre[None, :]
    lo, hi = seen[:, list(axes)].min(axis=0) - 0.1, seen[:, list(axes)].max(axis=0) + 0.1
    # equal scale on both axes (metres look like metres): widen the narrower range about its middle
    ratio = (H - 80) / (W - 80)
    mid, span = 0.5 * (lo + hi), max(hi[0] - lo[0], (hi[1] - lo[1]) / ratio)
    lo, hi = mid - 0.5 * span * np.array([1, ratio]), mid + 0.5 * span * np.array([1, ratio])
    ax = Axes(image, (lo[0], hi[0]), (lo[1], hi[1]), labels[0], labels[1])
    scene = np.array(rows["/world/scene"][0][1]["Points3D:positions"])
    inside = np.all((scene[:, axes] > lo) & (scene[:, axes] < hi), axis=1)
    ax.dots(scene[inside][:, axes[0]], scene[inside][:, axes[1]], (200, 200, 200), 1)
    half = np.array(target["Boxes3D:half_sizes"][0])
    q = np.array(target["Boxes3D:quaternions"][0])  # x y z w
    x, y, z, w = q
    R = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    world = corners @ R.T + centre
    hull = cv2.convexHull(np.stack(ax.px(world[:, axes[0]], world[:, axes[1]]), 1).astype(np.int32))
    cv2.polylines(image, [hull], True, (90, 220, 60), 2, cv2.LINE_AA)
    for _, r in rows.get("/world/arm/tcp_planned", []):
        strip = np.array(r["LineStrips3D:strips"][0])
        ax.line(strip[:, axes[0]], strip[:, axes[1]], (230, 130, 70), 2)
    if len(tcp):
        ax.dots(tcp[:, axes[0]], tcp[:, axes[1]], (60, 170, 40), 3)
    return image


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__)
        return 2
    rows = read(argv[0])
    t_end = max(t for entity in rows.values() for t, _ in entity) + 0.2
    outcome = rows["/outcome"][0][1]["TextDocument:text"][0].split("\n")[0].replace("**", "")
    panels = [
        camera_panel(rows, "fixed", "fixed camera, first frame: grounding candidates (best green)"),
        camera_panel(rows, "wrist", "wrist camera, last look: grounding candidates", k=-1),
        joints_panel(rows, t_end),
        gripper_panel(rows, t_end),
        paths_panel(rows, (0, 1), "TCP from above: planned (blue), measured (green), target box",
                    ("base x [m]", "base y [m]")),
        paths_panel(rows, (0, 2), "TCP from the side: approach and lift", ("base x [m]", "base z [m]")),
    ]  # fmt: skip
    grid = np.vstack([np.hstack(panels[k : k + 3]) for k in (0, 3)])
    banner = np.full((30, grid.shape[1], 3), 255, np.uint8)
    cv2.putText(banner, f"drawn from {argv[0]} (rerun recording, read back); outcome: {outcome}", (8, 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)  # fmt: skip
    cv2.imwrite(argv[1], np.vstack([banner, grid]), [cv2.IMWRITE_JPEG_QUALITY, 88])  # (.jpg: photos)
    print(f"wrote {argv[1]}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
