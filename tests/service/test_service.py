"""The perception service end to end: a real `prompose-grasp serve` process on a loopback port, spoken to
over HTTP by the package's client and by plain `urllib` requests."""

from __future__ import annotations

import base64
import http.client
import json
import os
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from prompose_grasp import InvalidInputError, ProMPose
from prompose_grasp.cli import main
from prompose_grasp.service import PerceptionClient, ServiceError

pytestmark = pytest.mark.sim  # the frame is rendered by the MuJoCo stand-in

ROOT = Path(__file__).resolve().parents[2]
TOKEN = "s3cret-test-token"
MAX_BODY_BYTES = 8 * 2**20  # the test server's limit: a 640 x 480 frame as PNG is ~0.5 MB, raw ~2.4 MB


@contextmanager
def _server(tmp_path: Path, *extra: str):
    """A `prompose-grasp serve --port 0` process; yields its URL; stopped (SIGTERM, then SIGKILL) at exit."""
    log = tmp_path / f"serve-{len(list(tmp_path.glob('serve-*')))}.log"
    with open(log, "w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "prompose_grasp.cli", "serve", "--port", "0", *extra],
            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err, env={**os.environ},
        )  # fmt: skip
    try:
        deadline = time.monotonic() + 180  # the estimator loads first: seconds, more on a loaded machine
        url = None
        while url is None:
            text = log.read_text()
            if "listening on " in text:
                url = text.split("listening on ", 1)[1].split()[0]
            elif proc.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"the server did not come up:\n{text[-2000:]}")
            else:
                time.sleep(0.2)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=30)


@pytest.fixture(scope="module")
def frame_files(tmp_path_factory):
    sys.path.insert(0, str(ROOT / "tests" / "perception"))
    from grounding_scene import render_scene

    scene = render_scene()
    d = tmp_path_factory.mktemp("frame")
    cv2.imwrite(str(d / "rgb.png"), scene.rgb[..., ::-1])
    depth_mm = np.round(scene.depth_m * 1000).astype(np.uint16)
    cv2.imwrite(str(d / "depth.png"), depth_mm)
    K = scene.intrinsics
    return {"rgb": d / "rgb.png", "depth": d / "depth.png", "K": (K.fx, K.fy, K.cx, K.cy),
            "rgb_array": scene.rgb, "depth_mm": depth_mm}  # fmt: skip


@pytest.fixture(scope="module")
def url(tmp_path_factory):
    with _server(tmp_path_factory.mktemp("server"), "--token", TOKEN, "--max-body-mb", "8") as u:
        yield u


@pytest.fixture(scope="module")
def client(url):
    return PerceptionClient(url, token=TOKEN)


def _post(url: str, path: str, body: bytes, headers: dict[str, str]) -> tuple[int, dict]:
    req = urllib.request.Request(url + path, data=body, headers=headers, method="POST")
    try:
        with urllib.request.urlopen(req, timeout=60) as resp:
            return resp.status, json.loads(resp.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def _cli_lines(capsys, argv: list[str]) -> tuple[int, str]:
    capsys.readouterr()
    code = main(argv)
    return code, capsys.readouterr().err.strip()


def test_the_server_answers_what_the_library_answers(client, frame_files):
    f = frame_files
    doc = client.estimate_files(f["rgb"], f["depth"], f["K"], "the blue box")
    # the same frame in this process, through the CLI's reading of the files
    from prompose_grasp.perception.frames_io import load_rgbd

    local = ProMPose.default().estimate_all(load_rgbd(f["rgb"], f["depth"], 0.001, f["K"]), "the blue box")
    assert doc["prompt"] == "the blue box" and doc["contenders"] == local[0].contenders
    assert set(doc["timing_ms"]) == {"grounding", "prior", "pose", "total"}
    assert len(doc["objects"]) == len(local)
    for got, want in zip(doc["objects"], local):
        want = want.to_dict()
        assert got["prior"] == want["prior"] and got["mask_pixels"] == want["mask_pixels"]
        for key in ("R", "t", "size", "score"):  # the same code on the same pixels: equal up to JSON floats
            np.testing.assert_allclose(got[key], want[key], rtol=0, atol=1e-12)
    # the frame as raw arrays (RGB uint8 + uint16 millimetres) gives the same answer as the PNG files
    raw = client.estimate(f["rgb_array"], f["depth_mm"], f["K"], "the blue box")
    assert raw["objects"] == doc["objects"]


def test_bad_input_is_a_400_with_the_message_the_cli_prints(client, url, frame_files, capsys):
    f = frame_files
    args = ["estimate", "--rgb", str(f["rgb"]), "--depth", str(f["rgb"]), "--intrinsics", *map(str, f["K"]),
            "--prompt", "the blue box"]  # fmt: skip
    code, local_line = _cli_lines(capsys, args)
    assert code == 2 and local_line.startswith("prompose-grasp estimate: error: ")
    assert "16-bit" in local_line  # a colour image given as depth
    os.environ["PROMPOSE_GRASP_TOKEN"] = TOKEN
    try:
        code, served_line = _cli_lines(capsys, [*args, "--server", url])
        assert code == 2 and served_line == local_line  # word for word, the path included
        bad_scale = ["--depth", str(f["depth"]), "--depth-scale", "1"]
        local = _cli_lines(capsys, [*args[:3], *bad_scale, *args[5:]])
        served = _cli_lines(capsys, [*args[:3], *bad_scale, *args[5:], "--server", url])
        assert served == local and "millimetres" in served[1]
    finally:
        del os.environ["PROMPOSE_GRASP_TOKEN"]
    with pytest.raises(InvalidInputError, match=r"no Latin letter|prompt"):
        client.estimate_files(f["rgb"], f["depth"], f["K"], "   ")
    with pytest.raises(InvalidInputError, match="bytes do not make"):
        client._call("POST", "/v1/estimate", {
            "prompt": "mug", "intrinsics": list(f["K"]),
            "rgb": {"raw": base64.b64encode(b"123").decode(), "shape": [480, 640, 3], "dtype": "uint8"},
            "depth": {"png": base64.b64encode(f["depth"].read_bytes()).decode()},
        })  # fmt: skip
    # a body that is not the request's shape: 422 with one line naming the field
    headers = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
    status, doc = _post(url, "/v1/estimate", b'{"prompt": "mug"}', headers)
    assert status == 422 and doc["error"].startswith("intrinsics:") and "\n" not in doc["error"]


def test_token_size_limit_and_schema(url, frame_files):
    assert PerceptionClient(url).health()["status"] == "ok"  # health needs no token
    with pytest.raises(ServiceError, match="401"):
        PerceptionClient(url).estimate_files(
            frame_files["rgb"], frame_files["depth"], frame_files["K"], "mug"
        )
    with pytest.raises(ServiceError, match="401"):
        PerceptionClient(url, token="wrong").health() and PerceptionClient(url, token="wrong").end_track("x")
    # a body over the limit is refused from its Content-Length, before a byte of it is read
    host, port = url.removeprefix("http://").rsplit(":", 1)
    conn = http.client.HTTPConnection(host, int(port), timeout=30)
    conn.putrequest("POST", "/v1/estimate")
    conn.putheader("Authorization", f"Bearer {TOKEN}")
    conn.putheader("Content-Length", str(MAX_BODY_BYTES + 1))
    conn.endheaders()
    resp = conn.getresponse()
    assert resp.status == 413 and "larger than the limit" in json.loads(resp.read())["error"]
    conn.close()
    with urllib.request.urlopen(url + "/openapi.json", timeout=30) as resp:  # the schema is public
        schema = json.loads(resp.read())
    assert {"/v1/health", "/v1/estimate", "/v1/track", "/v1/track/{track_id}"} <= set(schema["paths"])


def test_a_track_keeps_its_id_and_counts_its_frames(client, frame_files):
    f = frame_files
    first = client.track(f["rgb_array"], f["depth_mm"], f["K"], prompt="the blue box")
    tid = first["track_id"]
    assert first["frame"] == 0 and first["objects"][0]["prior"] == "box"
    second = client.track(f["rgb_array"], f["depth_mm"], f["K"], track_id=tid)
    assert second["track_id"] == tid and second["frame"] == 1
    # the same still frame: the tracked box stays where the first frame put it (2 cm: the window fusion
    # refits on the same points, nothing moves)
    np.testing.assert_allclose(second["objects"][0]["t"], first["objects"][0]["t"], atol=0.02)
    assert client.health()["tracks"] >= 1
    assert client.end_track(tid)["ended"] is True
    with pytest.raises(InvalidInputError, match="not an open track"):
        client.track(f["rgb_array"], f["depth_mm"], f["K"], track_id=tid)
    with pytest.raises(InvalidInputError, match="prompt is needed"):
        client.track(f["rgb_array"], f["depth_mm"], f["K"])


def test_parallel_clients_are_queued_and_all_answered_and_memory_stays_flat(client, frame_files):
    f = frame_files
    first = client.estimate_files(f["rgb"], f["depth"], f["K"], "the green bowl")

    def round_of(n_clients: int, per_client: int) -> list[object]:
        results: list[object] = []

        def worker() -> None:
            for _ in range(per_client):
                try:
                    results.append(client.estimate_files(f["rgb"], f["depth"], f["K"], "the green bowl"))
                except Exception as exc:  # collected and asserted below
                    results.append(exc)

        threads = [threading.Thread(target=worker) for _ in range(n_clients)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=300)
        return results

    before = client.health()
    first_round = round_of(4, 4)
    middle = client.health()
    second_round = round_of(4, 4)
    after = client.health()
    for results in (first_round, second_round):
        assert len(results) == 16
        assert all(isinstance(r, dict) and r["objects"] == first["objects"] for r in results), results[:1]
    assert after["answered"] - before["answered"] == 32 and after["waiting"] == 0
    if middle["rss_mb"] is not None:
        # The first round raises the peak (16 frames decoded at once while they wait, ~5 MB each); the
        # second round of the same load must not add to it: 24 MiB is less than 16 x 5 MB, which a leak of
        # every request's frame would add.
        assert after["rss_mb"] - middle["rss_mb"] < 24


def test_no_server_is_one_line_and_exit_2(frame_files, capsys):
    f = frame_files
    args = [
        "estimate",
        "--rgb",
        str(f["rgb"]),
        "--depth",
        str(f["depth"]),
        "--intrinsics",
        *map(str, f["K"]),
        "--prompt",
        "mug",
        "--server",
        "http://127.0.0.1:9",
    ]  # fmt: skip  (port 9: discard, nothing listens)
    code, line = _cli_lines(capsys, args)
    assert code == 2 and line.startswith("prompose-grasp estimate: error: no answer from http://127.0.0.1:9")
