"""Configs: validation, overrides, one-line errors, schemas kept in step with the models."""
from __future__ import annotations

import json
import typing
from pathlib import Path

import annotated_types
import pytest
from pydantic import BaseModel

from vfcli.store import layout
from vfcli.config import SCHEMA_MODELS, RecordingConfig, export_schemas, load_config
from vfcli.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def test_committed_schemas_match_the_models(tmp_path):
    written = export_schemas(tmp_path)
    # one schema per model, and no stale committed one (also keeps the loop below from being vacuous)
    assert sorted(p.name for p in written) == sorted(p.name for p in (ROOT / "schemas").glob("*.schema.json"))
    for p in written:
        committed = ROOT / "schemas" / p.name
        assert committed.exists(), f"schemas/{p.name} missing: run `make schemas`"
        assert json.loads(committed.read_text()) == json.loads(p.read_text()), f"schemas/{p.name} is out of date: run `make schemas`"
    assert sorted(p.name for p in (ROOT / "schemas").glob("*.schema.json")) == sorted(p.name for p in written)


def test_committed_layout_page_matches_the_layout():
    page = (ROOT / "docs" / "store-layout.md").read_text()
    assert page.strip() == layout.layout_markdown().strip(), "docs/store-layout.md is out of date: run `make schemas`"


def _numeric(annotation) -> bool:
    """A scalar int or float field (optionally None)."""
    if typing.get_origin(annotation) in (tuple, list, typing.Literal):
        return False
    args = typing.get_args(annotation) or (annotation,)
    return any(a in (int, float) for a in args)


@pytest.mark.parametrize("name", [n for n in SCHEMA_MODELS if n != "recording"])
def test_every_field_has_a_description_a_default_and_bounds(name):
    model: type[BaseModel] = SCHEMA_MODELS[name]
    for field_name, field in model.model_fields.items():
        assert field.description, f"{name}.{field_name} has no description"
        assert not field.is_required(), f"{name}.{field_name} has no default"
        if _numeric(field.annotation):
            kinds = {type(m) for m in field.metadata}
            assert kinds & {annotated_types.Gt, annotated_types.Ge}, f"{name}.{field_name} has no lower bound"
            assert kinds & {annotated_types.Lt, annotated_types.Le}, f"{name}.{field_name} has no upper bound"


def test_file_then_overrides(tmp_path):
    cfg = tmp_path / "rec.toml"
    cfg.write_text('name = "rig A"\n[camera]\npx_per_mm = 25.0\n[mesh]\ndepth_mm = 6.0\n')
    stored, effective = load_config(cfg, None, ["camera.px_per_mm=30", "flow.method=dis"])
    assert stored.camera.px_per_mm == 25.0 and stored.mesh.depth_mm == 6.0
    assert effective.camera.px_per_mm == 30.0 and effective.flow.method == "dis"
    assert effective.mesh.depth_mm == 6.0 and effective.name == "rig A"
    # the stored config comes back from JSON when no file is given
    again, _ = load_config(None, stored.model_dump_json(), None)
    assert again == stored


def test_null_unsets_a_field_that_may_be_unset_and_is_refused_for_one_that_may_not(tmp_path):
    cfg = tmp_path / "rec.toml"
    cfg.write_text("[optimize]\nn_frames = 50\n")
    stored, effective = load_config(cfg, None, ["optimize.n_frames=null", "name='null'"])
    assert stored.optimize.n_frames == 50 and effective.optimize.n_frames is None     # one glottal cycle
    assert effective.name == "null"                                                  # quoted: the string
    with pytest.raises(ConfigError, match="camera.px_per_mm = None"):
        load_config(cfg, None, ["camera.px_per_mm=null"])


@pytest.mark.parametrize(
    "text, needle",
    [
        ("[mesh]\ntarget_edge_mm = -1\n", "mesh.target_edge_mm = -1: Input should be greater than or equal to 0.7"),
        ("[mesh]\ntarget_edge = 0.5\n", "mesh.target_edge: unknown setting"),
        ("[flow]\nmethod = 'farneback'\n", "flow.method = 'farneback'"),
        ("[camera\n", "not valid TOML"),
    ],
)
def test_invalid_config_is_one_line_naming_field_and_value(tmp_path, text, needle):
    cfg = tmp_path / "rec.toml"
    cfg.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_config(cfg)
    msg = str(exc.value)
    assert needle in msg and "\n" not in msg and str(cfg) in msg


def test_invalid_value_exits_2_and_leaves_the_store_untouched(tmp_path, vfcli):
    store = tmp_path / "r.h5"
    good = tmp_path / "good.toml"
    good.write_text("[camera]\npx_per_mm = 25\n")
    assert vfcli("config", store, "--config", good).returncode == 0
    before = store.read_bytes()
    bad = tmp_path / "bad.toml"
    bad.write_text("[sync]\nmin_quality = 3\n")
    res = vfcli("config", store, "--config", bad)
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "sync.min_quality = 3" in res.stderr
    assert "Traceback" not in res.stderr
    res = vfcli("config", store, "--set", "camera.px_per_mm=-4")
    assert res.returncode == 2 and "camera.px_per_mm = -4" in res.stderr
    assert store.read_bytes() == before


def test_stored_config_is_updated_by_a_new_file(tmp_path, vfcli):
    store = tmp_path / "r.h5"
    cfg = tmp_path / "rec.toml"
    cfg.write_text("[camera]\npx_per_mm = 25\n")
    vfcli("config", store, "--config", cfg)
    cfg.write_text("[camera]\npx_per_mm = 40\n")
    vfcli("config", store, "--config", cfg)
    shown = json.loads(vfcli("config", store, "--show").stdout)
    assert shown["camera"]["px_per_mm"] == 40.0
    assert RecordingConfig.model_validate(shown).camera.px_per_mm == 40.0


def test_show_without_a_store_or_a_file_is_one_line_and_share_without_video_names_the_missing_stage(tmp_path, vfcli):
    """`vfcli config nothere.h5 --show` printed the defaults with exit 0, as if a mistyped store held them; `vfcli
    share` of a store without /hsc exited 2 where the documented code for a missing stage is 5 (session 35)."""
    missing = tmp_path / "nothere.h5"
    res = vfcli("config", missing, "--show")
    assert res.returncode == 2 and res.stdout == "" and len(res.stderr.strip().splitlines()) == 1, res
    assert "no such store file" in res.stderr and not missing.exists()
    cfg = tmp_path / "rec.toml"
    cfg.write_text("[camera]\npx_per_mm = 25\n")
    shown = json.loads(vfcli("config", missing, "--config", cfg, "--show").stdout)   # what the file gives
    assert shown["camera"]["px_per_mm"] == 25.0
    store = tmp_path / "r.h5"
    assert vfcli("config", store, "--config", cfg).returncode == 0                   # a store with its config only
    res = vfcli("share", store, tmp_path / "out.h5")
    assert res.returncode == 5 and "run `vfcli ingest-hsc` first" in res.stderr, res.stderr
    assert not (tmp_path / "out.h5").exists()


@pytest.mark.parametrize("item, field", [("camera.px_per_mm=true", "px_per_mm = true"),
                                         ("mesh.n_harmonics=false", None),
                                         ("camera.offset_px=[true, 2]", "offset_px = [true, 2]"),
                                         ("optimize.n_frames=true", "n_frames = true")])
def test_true_or_false_where_a_number_is_meant_is_a_config_error(item, field):
    """pydantic reads `camera.px_per_mm = true` as 1.0: it was stored so (session 35); a flag stays a flag."""
    if field is None:     # an unknown key is still named as one
        with pytest.raises(ConfigError, match="unknown setting"):
            load_config(None, None, [item])
        return
    with pytest.raises(ConfigError) as err:
        load_config(None, None, [item])
    assert f"{field}: a number is meant here, not true/false" in str(err.value) and "Value error" not in str(err.value)
    _, cfg = load_config(None, None, ["flow.subpixel_edges=false", "optimize.tie_folds=true"])
    assert cfg.flow.subpixel_edges is False and cfg.optimize.tie_folds is True


def test_the_example_config_is_valid_and_spells_out_the_defaults():
    stored, _ = load_config(ROOT / "examples" / "recording.toml")
    assert stored == RecordingConfig()
    # the settings a lab measures are left unset, so their warnings stay on for a lab that starts from it (written
    # out, px_per_mm = 20.0 silenced the warning about the placeholder scale: hF, session 37)
    from vfcli.calibration import default_calibration
    from vfcli.calibration import MEASURED_SETTINGS

    assert default_calibration(stored, stored, MEASURED_SETTINGS) == list(MEASURED_SETTINGS)


def test_the_store_keeps_only_the_settings_the_file_gave(tmp_path, vfcli):
    """Defaults are not frozen into a store: a newer vfcli's defaults apply to what the file left out."""
    from vfcli.store import Store

    store, cfg = tmp_path / "r.h5", tmp_path / "rec.toml"
    cfg.write_text("[camera]\npx_per_mm = 25\n")
    assert vfcli("config", store, "--config", cfg).returncode == 0
    with Store(store).read() as r:
        assert json.loads(r.recording_config_json()) == {"camera": {"px_per_mm": 25.0}}


def test_a_calibrated_zero_pose_can_be_stated_and_a_pose_without_camera_pose_is_refused(tmp_path):
    import numpy as np

    from vfcli.inverse.setup import OptimizeInputs, camera_pose

    bad = tmp_path / "bad.toml"
    bad.write_text("[camera]\nrotation_deg = 2.0\noffset_px = [10.0, 20.0]\n")
    with pytest.raises(ConfigError, match="camera.pose"):
        load_config(bad)
    # the same by --set: it was taken with the pose estimated, the rotation silently unused (the run's config
    # was built from every default, camera.pose among them, so the check saw a pose stated)
    with pytest.raises(ConfigError, match="--set: .*camera.pose is not"):
        load_config(None, None, ["camera.rotation_deg=2.0"])
    assert load_config(None, None, ["camera.rotation_deg=2.0", "camera.pose='config'"])[1].camera.rotation_deg == 2.0
    zero = tmp_path / "zero.toml"
    zero.write_text("[camera]\npose = 'config'\n")
    cfg = load_config(zero)[0].camera
    assert (cfg.pose, cfg.rotation_deg, cfg.offset_px) == ("config", 0.0, (0.0, 0.0))
    inputs = OptimizeInputs(mesh=None, youngs_modulus_pa=1.0, poisson_ratio=0.3, density_kg_m3=1.0, length_mm=15.0,
                            times=np.zeros(2), velocity=np.zeros((2, 4, 5, 3)), valid=np.zeros((2, 4, 5), bool),
                            gap_masks=np.zeros((2, 4, 5), bool), px_per_mm=10.0, roi_origin_px=np.array([3.0, 7.0]))
    # the zero pose is used as given (no gap counts: estimating would need them), moved onto the ROI's grid
    assert camera_pose(inputs, (cfg.rotation_deg, cfg.offset_px)) == (0.0, (-3.0, -7.0), "config")
    with pytest.raises(ValueError, match="gap_counts"):
        camera_pose(inputs, None)


@pytest.mark.parametrize("value", ["lbfgs", "3x3x10-one-sided", "true", "null", "12", " padded", "a=b", None, 3, 1e-05,
                                   True, [4, 3], ["a", "b"]])
def test_a_settings_value_written_as_a_set_item_reads_back_as_itself(value):
    """The --set items `vfcli info` prints to resume a stopped fit (vfcli.store.checkpoint.resume_flags) must
    give back the checkpoint's settings: a string that would read as another value ("true", "12") is quoted."""
    from vfcli.overrides import apply_overrides, override_item

    item = override_item("optimize.k", value)
    assert apply_overrides({}, [item])["optimize"]["k"] == value
