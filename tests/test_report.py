"""`vfcli report`: one self-contained page (every picture and the video inline and decodable, no script,
no network), the store untouched, and `--index` linking the reports of many recordings."""
from __future__ import annotations

import base64
import hashlib
import shutil
from html.parser import HTMLParser

import numpy as np
import pytest

from _export_store import optimised_store
from conftest import run_vfcli
from vfcli.store.parts import copy_store


class _Refs(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.refs: list[tuple[str, str, str]] = []
        self.tags: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        for k, v in attrs:
            if k in ("src", "href", "poster", "data") and v is not None:
                self.refs.append((tag, k, v))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    store = optimised_store(tmp_path_factory)
    d = tmp_path_factory.mktemp("report")
    copy = d / "rec.h5"
    copy_store(store, copy)
    before = hashlib.sha256(copy.read_bytes()).hexdigest(), copy.stat().st_mtime_ns
    res = run_vfcli("report", copy, "--out", d / "report.html")
    assert res.returncode == 0, res.stderr
    assert (hashlib.sha256(copy.read_bytes()).hexdigest(), copy.stat().st_mtime_ns) == before
    return d / "report.html"


def test_report_is_self_contained_and_every_picture_decodes(report):
    import cv2
    import imageio_ffmpeg

    text = report.read_text()
    p = _Refs()
    p.feed(text)
    assert "script" not in p.tags
    assert "http://" not in text and "https://" not in text
    images = [v for tag, _, v in p.refs if tag == "img"]
    videos = [v for tag, _, v in p.refs if tag == "video"]
    assert all(v.startswith("data:") for _, _, v in p.refs)
    assert len(images) >= 10 and len(videos) == 1
    for uri in images:
        head, b64 = uri.split(",", 1)
        img = cv2.imdecode(np.frombuffer(base64.b64decode(b64), np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and img.shape[0] > 50 and img.shape[1] > 50, head
    mp4 = report.with_name("v.mp4")
    mp4.write_bytes(base64.b64decode(videos[0].split(",", 1)[1]))
    frames = list(imageio_ffmpeg.read_frames(str(mp4)))
    assert len(frames) > 2
    assert report.stat().st_size < 6e6  # light: a few MB at most


def test_report_names_every_stage_and_run(report):
    text = report.read_text()
    for s in ("/hsc", "/ldv", "/sync", "/flow", "/fields", "/mesh", "/optimize/pressure", "/optimize/free"):
        assert f">{s}<" in text, s
    assert "Optimisation runs" in text and "3x3x10-one-sided" in text
    assert "Diagnosis" in text


def test_index_links_the_reports_of_many_recordings(report, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    copy_store(report.with_name("rec.h5"), a / "rec.h5")
    shutil.copy2(report, a / "rec.html")
    copy_store(report.with_name("rec.h5"), b / "other.h5")
    (tmp_path / "notes.h5").write_bytes(b"not hdf5")
    res = run_vfcli("report", "--index", tmp_path)
    assert res.returncode == 0, res.stderr
    text = (tmp_path / "index.html").read_text()
    p = _Refs()
    p.feed(text)
    links = [v for tag, k, v in p.refs if tag == "a"]
    assert links == ["a/rec.html"]
    assert "b/other.h5" in text and "no report" in text and "2 store(s)" in text


def test_report_without_file_or_with_both_is_a_usage_error(tmp_path):
    res = run_vfcli("report")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    res = run_vfcli("report", tmp_path / "x.h5", "--index", tmp_path)
    assert res.returncode == 2 and "Traceback" not in res.stderr
