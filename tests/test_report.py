"""`vfcli report`: one self-contained page (every picture and the video inline and decodable, no script,
no network), the store untouched, and `--index` linking the reports of many recordings."""
from __future__ import annotations

import base64
import html
import json
import re
import shutil
from pathlib import Path
from html.parser import HTMLParser

import numpy as np
import pytest

from _diagnose_phantom import CONTACT_PHANTOM, ONE_SIDED_FIT, shared_diagnosed_phantom
from _export_store import optimised_report
from conftest import run_vfcli
from vfcli.store import Store
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
    """report.html of the shared optimised store's copy rec.h5 beside it, the copy checked unchanged by the
    report (:func:`_export_store.optimised_report`, shared with tests/test_report_browser.py; read-only)."""
    return optimised_report(tmp_path_factory)


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


def test_the_gap_frames_captions_name_the_frame_its_time_and_the_gap_the_store_holds(report):
    """Each of the four outlined frames is captioned in the page's text with its frame, time and the detected
    gap's size, as /flow stores them (the same words burned into the thumbnail were a few pixels high)."""
    gap = _section(report.read_text(), "Glottal gap and flow")
    captions = re.findall(r"<figcaption>frame (\d+), t = ([\d.]+) ms: (?:the detected gap \((\d+) px\) outlined in red|"
                          r"(no gap detected))</figcaption>", gap)
    assert len(captions) == 4
    with Store(report.with_name("rec.h5")).read() as r:
        masks = r.read("flow", "gap_mask")
        times = r.read("flow", "frame_time")
    for frame, ms, px, none in captions:
        k = int(frame)
        assert float(ms) == pytest.approx(1e3 * times[k], abs=0.006)
        assert (int(px) if px else 0) == int(masks[k].sum()) and bool(none) == (masks[k].sum() == 0)
    assert any(px for _, _, px, _ in captions) and len({c[0] for c in captions}) == 4


def _section(page: str, title: str) -> str:
    """The text of the page's section ``title`` (from its heading to the next <h2>), entities unescaped."""
    return html.unescape(page.split(f"<h2>{title}</h2>", 1)[1].split("<h2>", 1)[0])


def test_every_stored_warning_is_shown_at_a_glance_once_without_the_loggers_prefix(report):
    """The warnings the stages stored (their summary's logged lines and their notes, which repeat them) are
    listed at the top of the page, each once, as the sentence a user reads; so is what is not written yet."""
    glance = _section(report.read_text(), "At a glance")
    messages, notes = [], []
    with Store(report.with_name("rec.h5")).read() as r:
        for path in r.stage_paths():
            stage, _, run = path.strip("/").partition("/")
            attrs = r.attrs(stage, run or None)
            logged = json.loads(attrs.get("summary_json", "{}")).get("warnings", [])
            messages += [re.sub(r"^WARNING [\w.]+: ", "", w) for w in logged]
            if "notes" in attrs:
                notes += json.loads(attrs["notes"])
    print(f"{len(messages)} logged warning(s), {len(notes)} note(s)")
    assert len(messages) >= 2 and notes                    # measured: 3 logged, 1 note (the dropouts, twice)
    for m in messages + notes:
        assert glance.count(m) == 1, m
    assert f"{len(set(messages))} warning(s) stored by the stages" in glance
    assert "WARNING vfcli" not in glance
    assert "Not written yet: /diagnose" in glance


def test_a_stage_made_stale_by_a_config_change_is_named_at_a_glance(report, tmp_path):
    store = tmp_path / "rec.h5"
    copy_store(report.with_name("rec.h5"), store)
    res = run_vfcli("config", store, "--set", "sync.n_harmonics=8")
    assert res.returncode == 0, res.stderr
    res = run_vfcli("report", store, "--out", tmp_path / "r.html")
    assert res.returncode == 0, res.stderr
    glance = _section((tmp_path / "r.html").read_text(), "At a glance")
    stale = dict(re.findall(r"<code>(/[\w/]+)</code> is STALE: (.*?) \(rerun it", glance))
    print(stale)
    assert stale["/sync"] == "config changed: sync.n_harmonics 10 -> 8"
    assert "/sync is stale" in stale["/fields"]
    # as `vfcli info` says (the mesh too: the store's config has the default edge, the mesh was made at 2.5 mm)
    info = json.loads(run_vfcli("info", "--json", store).stdout)
    assert stale == {st["path"]: "; ".join(st["stale_because"]) for st in info["stages"] if st["stale"]}


@pytest.fixture(scope="module")
def diagnosed_report(tmp_path_factory):
    """(folder of the shared diagnosed contact phantom (:func:`_diagnose_phantom.shared_diagnosed_phantom`, read-only),
    the page `vfcli report` writes of its store)."""
    seed, synth = CONTACT_PHANTOM
    folder = shared_diagnosed_phantom(tmp_path_factory, seed, ONE_SIDED_FIT, synth)
    out = tmp_path_factory.mktemp("diagnosed_report") / "r.html"
    res = run_vfcli("report", folder / "rec.h5", "--out", out)
    assert res.returncode == 0, res.stderr
    return folder, out


def test_a_diagnosis_verdict_is_shown_at_a_glance_and_its_stored_json_is_folded_away(diagnosed_report):
    store = diagnosed_report[0] / "rec.h5"
    page = diagnosed_report[1].read_text()
    with Store(store).read() as r:
        attrs = r.attrs("diagnose", "fit")
    words = json.loads(attrs["words_json"])
    # this short phantom holds too few cycles to calibrate: its verdict is the line saying so
    assert "decision" not in attrs
    verdict = next(w for w in words if w.startswith("decision: not calibrated"))[len("decision: "):]
    print(verdict)
    assert f"Diagnosis <code>/diagnose/fit</code>: <strong>{verdict}</strong>" in html.unescape(page)
    diagnosis = page.split("<h2>Diagnosis</h2>", 1)[1]
    folded = diagnosis.index("Everything the diagnosis stored (JSON)")
    assert diagnosis.index(html.escape(words[0], quote=True)) < folded
    for key in ("manifest_json", "words_json", "summary_json"):
        assert key not in diagnosis[:folded], key
    assert "manifest_json" in diagnosis[folded:]
    # where the diagnosis' time went, step by step, shown beside its figures (not folded away)
    shown = diagnosis.index("time by step")
    assert shown < folded and diagnosis[shown:folded].split("</tr>")[0].count(" s, ") >= 3


def test_the_diagnosis_pictures_are_in_the_page_and_a_moved_one_is_named(diagnosed_report, tmp_path):
    """The page showed the diagnosis' words only: its residual maps and velocity plots were files beside the store
    or its --map. Now: the RMS residual of the diagnosed run, drawn from the stored /diagnose/<run>/rms_residual,
    and every picture the diagnosis names in its stored "images" (--map's first), embedded byte for byte; a
    picture no longer where the diagnosis wrote it is named as missing."""
    from vfcli.stages.report import _diagnosis_pictures

    folder, page = diagnosed_report
    diagnosis = html.unescape(page.read_text().split("<h2>Diagnosis</h2>", 1)[1])
    with Store(folder / "rec.h5").read() as r:
        images = json.loads(r.attrs("diagnose", "fit")["summary_json"])["figures"]["images"]
        assert Path(images["before"]) == folder / "maps" / "map.png"
        # the --map picture in the page, the very file
        uri = "data:image/png;base64," + base64.b64encode((folder / "maps" / "map.png").read_bytes()).decode()
        assert uri in diagnosis and "Residual map of run fit (where, and when in the cycle" in diagnosis
        rms = re.search(r'<img src="data:image/png;base64,([^"]+)" alt="Where run fit and the recording disagree', diagnosis)
        import cv2
        img = cv2.imdecode(np.frombuffer(base64.b64decode(rms.group(1)), np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and min(img.shape[:2]) > 300
        gone = tmp_path / "moved" / "map_refit.png"
        part = _diagnosis_pictures(r, "/diagnose/fit", {"before": str(folder / "maps" / "map.png"), "after": str(gone)},
                                   tmp_path)
    assert "no longer there (moved or deleted): " + str(gone) in html.unescape(part)
    assert part.count("<img") == 2          # the RMS residual and the --map picture


def test_a_stages_time_by_step_reads_in_the_order_run_with_its_sum():
    from vfcli.stages.report import phase_times

    assert phase_times({"read": 6.5, "profile": 108.0, "write": 0.099}) == \
        "read 6.5 s, profile 108 s, write 0.099 s; 115 s in all"


def test_the_verdict_at_a_glance_names_the_unconfirmed_leads_as_the_terminal_does():
    """The report showed "no missing physics detected" where the terminal printed "... (unconfirmed lead:
    contact)": the stored decision is the verdict alone, the printed line names the leads."""
    from vfcli.stages.report import _verdict

    words = ["f0 120 Hz ...", "contact: a calibrated lead (family-wise p = 0.025), its refit does not predict ...",
             "no missing physics detected (unconfirmed lead: contact)"]
    attrs = {"decision": "no missing physics detected", "words_json": json.dumps(words),
             "refit_run": "default+contact", "refit_candidate": "contact"}
    assert _verdict(attrs) == ("no missing physics detected (unconfirmed lead: contact) (refit with contact stored "
                               "as run default+contact)")
    assert _verdict({"decision": "missing physics: asymmetry", "words_json": "[]"}) == "missing physics: asymmetry"


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


def test_index_says_per_recording_its_warnings_stale_stages_and_diagnosis(report, tmp_path):
    """The overview listed stages and runs only: a lab scanning fifty recordings could not see which ones warned,
    went stale or were diagnosed with missing physics without opening every page. Its warnings by stage are the
    report page's, its stale stages `vfcli info`'s, its verdict the page's "At a glance"."""
    copy_store(report.with_name("rec.h5"), tmp_path / "a" / "rec.h5")
    copy_store(report.with_name("rec.h5"), tmp_path / "b" / "rec.h5")
    assert run_vfcli("config", tmp_path / "b" / "rec.h5", "--set", "sync.n_harmonics=8").returncode == 0
    res = run_vfcli("report", "--index", tmp_path)
    assert res.returncode == 0, res.stderr
    rows = re.findall(r"<tr>(.*?)</tr>", html.unescape((tmp_path / "index.html").read_text()), re.S)
    cells = {re.sub(r"<.*?>", "", r.split("</td>")[0]).split(" ")[0].removeprefix("<td>"):
             [re.sub(r"<.*?>", "", c) for c in re.findall(r"<td>(.*?)</td>", r, re.S)] for r in rows[1:]}
    assert sorted(cells) == ["a/rec.h5", "b/rec.h5"]
    page = report.read_text()
    stages = re.findall(r"<tr><td>(/[\w/+]+)</td>(?:<td>.*?</td>){5}<td>(\d+)</td></tr>", page)
    warned = [f"{path.strip('/')} {n}" for path, n in stages if int(n)]
    assert warned, "the shared store's stages store warnings"
    expected = f"{sum(int(n) for _, n in stages)}: {', '.join(warned)}"
    assert cells["a/rec.h5"][4] == cells["b/rec.h5"][4] == expected
    for rec in ("a", "b"):   # (the shared store's mesh is stale already: made at 2.5 mm, its config says 1.5)
        info = json.loads(run_vfcli("info", "--json", tmp_path / rec / "rec.h5").stdout)
        assert cells[f"{rec}/rec.h5"][5] == ", ".join(st["path"].strip("/") for st in info["stages"] if st["stale"])
    assert "sync" in cells["b/rec.h5"][5].split(", ") and "sync" not in cells["a/rec.h5"][5].split(", ")
    assert cells["a/rec.h5"][6] == "not diagnosed"


def test_index_says_a_diagnosed_recordings_verdict(diagnosed_report, tmp_path):
    folder = diagnosed_report[0]
    copy_store(folder / "rec.h5", tmp_path / "c" / "rec.h5")
    res = run_vfcli("report", "--index", tmp_path)
    assert res.returncode == 0, res.stderr
    text = html.unescape((tmp_path / "index.html").read_text())
    with Store(folder / "rec.h5").read() as r:
        words = json.loads(r.attrs("diagnose", "fit")["words_json"])
    # this short phantom holds too few cycles to calibrate: its verdict is the line saying so, as at a glance
    verdict = next(w for w in words if w.startswith("decision: not calibrated"))[len("decision: "):]
    assert f"<td>fit: {verdict}</td>" in text


def test_report_without_file_or_with_both_is_a_usage_error(tmp_path):
    res = run_vfcli("report")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    res = run_vfcli("report", tmp_path / "x.h5", "--index", tmp_path)
    assert res.returncode == 2 and "Traceback" not in res.stderr
