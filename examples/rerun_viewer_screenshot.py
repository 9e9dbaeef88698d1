"""A screenshot of the rerun viewer showing a recording, taken without a display.

The viewer runs headless (rerun's `ViewerClient.spawn(headless=True)`, extra `viz`), opens the .rrd, moves its
time cursor to `SECONDS` on the episode's timeline, and saves what it draws:

    MUJOCO_GL=egl prompose-grasp demo --command "pick up the green bottle" --out demo_out \
        --rerun demo_out/episode.rrd
    python examples/rerun_viewer_screenshot.py demo_out/episode.rrd docs/images/rerun_viewer.jpg 2.3

The viewer renders with wgpu, so it needs a Vulkan adapter. On a machine without a GPU, Mesa's software
rasterizer serves (Debian/Ubuntu: `apt-get install mesa-vulkan-drivers`; this script points Vulkan at its
`lvp` driver when no other is chosen). It is slow (tens of seconds for a 1920 x 1080 frame) but exact.
"""

from __future__ import annotations

import os
import shutil
import sys
import time
from pathlib import Path

LAVAPIPE_ICD = Path("/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")


def screenshot(recording: str, out: str, seconds: float, port: int = 9877) -> None:
    if "VK_ICD_FILENAMES" not in os.environ and LAVAPIPE_ICD.is_file():
        os.environ["VK_ICD_FILENAMES"] = str(LAVAPIPE_ICD)
    from rerun.experimental import ViewerClient

    # the `rerun` executable of this interpreter's environment (the venv's bin is not always on PATH)
    exe = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    if exe is None:
        raise SystemExit("the rerun viewer executable was not found: pip install 'prompose-grasp[viz]'")
    viewer = ViewerClient.spawn(headless=True, port=port, hide_welcome_screen=True, executable_path=exe)
    try:
        viewer.open(str(Path(recording).resolve()))
        deadline = time.monotonic() + 120.0
        while viewer.get_state().loading and time.monotonic() < deadline:
            time.sleep(0.5)
        viewer.set_time("episode", duration=seconds, play_state="paused")
        time.sleep(3.0)  # a few frames of the software rasterizer, so every view has drawn at the new time
        tmp = Path(out).with_suffix(".png")
        viewer.save_screenshot(str(tmp))
    finally:
        viewer.quit()
    if Path(out).suffix.lower() in (".jpg", ".jpeg"):
        import cv2

        cv2.imwrite(out, cv2.imread(str(tmp)), [cv2.IMWRITE_JPEG_QUALITY, 85])
        tmp.unlink()
    print(f"wrote {out}")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        raise SystemExit(__doc__)
    screenshot(sys.argv[1], sys.argv[2], float(sys.argv[3]))
