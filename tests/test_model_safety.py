"""Nothing loaded from a model directory runs code, and a broken or tampered directory is one
line with exit code 2: hostile skops trees, part paths that leave the directory, damaged
model.json, parts missing, damaged or changed since they were saved."""

from __future__ import annotations

import io
import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_targets import ideal_tests

from features.readings import read_readings
from features.readings.errors import InputError
from models.estimators.training import fit_model
from models.serving import persistence, registry
from pipeline.cli import main


@pytest.fixture(scope="module")
def readings_csv(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("data") / "readings.csv"
    ideal_tests(direct=True).to_csv(path, index=False)
    return path


FITS = {}  # name -> the fit whose directory ``trained`` wrote


@pytest.fixture(scope="module")
def trained(readings_csv, tmp_path_factory) -> dict[str, Path]:
    """Model directories of each save format: skops (knn), plain JSON (bspline), the
    estimator's own (shallow-lm) and with parts (hybrid)."""
    from features.table import feature_table

    table = feature_table(read_readings(readings_csv, "auto"), target="auto")
    root = tmp_path_factory.mktemp("models")
    fits = {name: fit_model(table, name) for name in ("knn", "bspline", "hybrid", "shallow-lm")}
    for name, fit in fits.items():
        registry.save_model(fit.trained_model(), root / name)
    FITS.update(fits)
    return {name: root / name for name in fits}


@pytest.fixture
def model_copy(trained, tmp_path):
    def copy(name: str) -> Path:
        return Path(shutil.copytree(trained[name], tmp_path / "models" / name))
    return copy


def one_error_line(capsys) -> str:
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("backlash "), err
    return err[0]


def edit_json(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def rehash(model_dir: Path) -> None:
    """What an attacker who controls the whole folder does: make model.json agree again."""
    def update(meta):
        meta["estimator"]["sha256"] = persistence.digest(model_dir / meta["estimator"]["path"])
    edit_json(model_dir / "model.json", update)


# ----------------------------------------------------------------------------- hostile trees

def call_node(module: str, function: str, *args: str) -> dict:
    """A skops node that calls ``module.function(*args)`` when the tree is constructed."""
    strings = [{"__class__": "str", "__module__": "builtins", "__loader__": "JsonNode",
                "content": json.dumps(a), "is_json": True, "__id__": 9000 + i}
               for i, a in enumerate(args)]
    return {"__class__": function, "__module__": module,
            "__loader__": "ConstructorFromReduceNode", "__id__": 8000,
            "content": {"__class__": "tuple", "__module__": "builtins", "__loader__": "TupleNode",
                        "content": strings, "__id__": 8001}}


def plant(skops_file: Path, node: dict) -> bytes:
    """Put ``node`` in the place of the pipeline's ``memory`` attribute (None when saved)."""
    with zipfile.ZipFile(skops_file) as archive:
        files = {n: archive.read(n) for n in archive.namelist()}
    schema = json.loads(files["schema.json"])
    schema["content"]["content"]["memory"] = node
    files["schema.json"] = json.dumps(schema).encode()
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, data in files.items():
            archive.writestr(name, data)
    skops_file.write_bytes(buffer.getvalue())
    return buffer.getvalue()


def writes(marker: Path) -> str:
    return f"open({str(marker)!r}, 'w').write('code ran')"


@pytest.mark.parametrize("module, function, payload", [
    ("builtins", "exec", writes),
    ("builtins", "eval", lambda m: f"__import__('pathlib').Path({str(m)!r}).write_text('ran')"),
    ("sklearn.utils._testing", "assert_run_python_script_without_output", writes),
])
def test_hostile_skops_tree_is_refused_and_runs_nothing(model_copy, readings_csv, tmp_path,
                                                        capsys, module, function, payload):
    model_dir = model_copy("knn")
    marker = tmp_path / "marker"
    data = plant(model_dir / "estimator.skops", call_node(module, function, payload(marker)))
    rehash(model_dir)
    pred = tmp_path / "pred.csv"
    assert main(["predict", str(model_dir), str(readings_csv), "--out", str(pred)]) == 2
    line = one_error_line(capsys)
    assert "refusing" in line and f"{module}.{function}" in line, line
    assert not marker.exists() and not pred.exists()
    if module == "builtins":
        # the planted tree is real: a loader that trusts what it finds runs it
        import skops.io

        skops.io.loads(data, trusted=skops.io.get_untrusted_types(data=data))
        assert marker.exists()


def test_types_outside_the_allow_list_are_refused_even_from_trusted_packages(model_copy):
    """An sklearn object the product never saves, planted as plain data, is refused."""
    model_dir = model_copy("knn")
    node = {"__class__": "FunctionTransformer", "__module__": "sklearn.preprocessing._function_"
            "transformer", "__loader__": "ObjectNode", "__id__": 8100}
    plant(model_dir / "estimator.skops", node)
    rehash(model_dir)
    with pytest.raises(InputError, match="FunctionTransformer"):
        registry.load_model(model_dir)


def test_the_allow_list_is_exactly_what_the_skops_saved_predictors_need(tmp_path):
    """Every registered predictor saved as skops needs every allowed type and no other; the
    only builtins allowed are plain data types, never callables."""
    import skops.io
    from test_estimators import fast

    rng = np.random.default_rng(0)
    X = pd.DataFrame(rng.uniform(0, 1, (40, 3)), columns=["target", "feed_mm_min", "dwell_s"])
    y = rng.normal(size=40)
    needed = set()
    for name in registry.names():
        spec = persistence.save_estimator(fast(registry.make(name)).fit(X, y), tmp_path, name)
        if spec["format"] == "skops":
            data = (tmp_path / spec["path"]).read_bytes()
            types = {t for _, t in persistence.skops_nodes(data)}
            assert set(skops.io.get_untrusted_types(data=data)) <= types
            needed |= types
    assert needed == persistence.SKOPS_TYPES
    assert {t for t in needed if t.startswith("builtins.")} <= {
        "builtins.dict", "builtins.list", "builtins.tuple", "builtins.str", "builtins.int",
        "builtins.float", "builtins.bool"}


# ----------------------------------------------------------------------------- path escapes

@pytest.mark.parametrize("escape", ["../outside", "/etc/passwd", "residual/../../outside"])
def test_hybrid_parts_outside_the_model_directory_are_refused(model_copy, tmp_path, escape):
    model_dir = model_copy("hybrid")
    shutil.copytree(model_dir / "estimator" / "residual", tmp_path / "models" / "outside")
    edit_json(model_dir / "estimator" / "hybrid.json",
              lambda parts: parts["residual"].update(path=escape))
    rehash(model_dir)
    with pytest.raises(InputError, match="part path"):
        registry.load_model(model_dir)


def test_a_symlink_out_of_the_model_directory_is_refused(model_copy, tmp_path):
    model_dir = model_copy("hybrid")
    outside = Path(shutil.copytree(model_dir / "estimator" / "residual", tmp_path / "elsewhere"))
    shutil.rmtree(model_dir / "estimator" / "residual")
    (model_dir / "estimator" / "residual").symlink_to(outside, target_is_directory=True)
    rehash(model_dir)
    with pytest.raises(InputError, match="leads outside the model directory"):
        registry.load_model(model_dir)


def test_model_json_cannot_point_outside(model_copy):
    model_dir = model_copy("bspline")
    edit_json(model_dir / "model.json", lambda m: m["estimator"].update(path="../bspline.json"))
    with pytest.raises(InputError, match="must be a plain name inside the model directory"):
        registry.load_model(model_dir)


# ----------------------------------------------------------------------------- broken folders

def _set(*keys_value):
    *keys, value = keys_value

    def change(meta):
        target = meta
        for key in keys[:-1]:
            target = target[key]
        target[keys[-1]] = value
    return change


def _flip_last_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[-1] ^= 0xFF
    path.write_bytes(bytes(data))


def _network_state(change):
    """Rewrite the network's state dict (still tensors and plain values only), then rehash."""
    def damage(model_dir: Path) -> None:
        import torch

        path = model_dir / "estimator" / "network.pt"
        state = torch.load(path, weights_only=True)
        change(state)
        torch.save(state, path)
        rehash(model_dir)
    return damage


BROKEN = {
    "not json": ("bspline", lambda d: (d / "model.json").write_text("{\"name\": "),
                 "not valid JSON"),
    "no estimator key": ("bspline", lambda d: edit_json(d / "model.json",
                                                        lambda m: m.pop("estimator")),
                         "lacks the key 'estimator'"),
    "features not a list": ("bspline", lambda d: edit_json(d / "model.json",
                                                           _set("features", "target")),
                            "'features' has the wrong type"),
    "features reordered": ("bspline", lambda d: edit_json(
        d / "model.json", lambda m: m["features"].reverse()), "'features' differs from"),
    "unknown predictor": ("bspline", lambda d: edit_json(d / "model.json",
                                                         _set("name", "transformer")),
                          "unknown predictor 'transformer'"),
    "estimator spec not text": ("bspline", lambda d: edit_json(
        d / "model.json", _set("estimator", "format", 3)), "lacks the text key 'format'"),
    "class swapped": ("bspline", lambda d: edit_json(
        d / "model.json", _set("estimator", "class", "os.system")),
        "refusing estimator class 'os.system'"),
    "part missing": ("bspline", lambda d: (d / "estimator.json").unlink(),
                     "'estimator.json' is missing"),
    "part changed": ("bspline", lambda d: edit_json(
        d / "estimator.json", _set("state", "range_", {"tuple": [0.0, 1e9]})),
        "does not match its sha256"),
    "network weights damaged": ("hybrid", lambda d: _flip_last_byte(
        d / "estimator" / "residual" / "network.pt"), "does not match its sha256"),
    "skops zip damaged": ("knn", lambda d: _flip_last_byte(d / "estimator.skops"),
                          "does not match its sha256"),
    "skops zip corrupt, hash updated": ("knn", lambda d: ((d / "estimator.skops").write_bytes(
        b"PK\x03\x04 not a zip"), rehash(d)), "not a readable skops file"),
    "json part corrupt, hash updated": ("bspline", lambda d: (
        (d / "estimator.json").write_text("{\"params\": {}, \"state\": {\"x_\": {\"eval\": 1}}}"),
        rehash(d)), "cannot read model part"),
    "hybrid.json broken, hash updated": ("hybrid", lambda d: (
        (d / "estimator" / "hybrid.json").write_text("[]"), rehash(d)), "broken hybrid.json"),
    "network activation unknown, hash updated": ("shallow-lm", _network_state(
        lambda state: state["params"].update(activation="evil")), "unknown activation 'evil'"),
    "network weights truncated, hash updated": ("shallow-lm", _network_state(
        lambda state: state.update(weights=state["weights"][:-3])),
        "the weights do not fit the layer sizes"),
    "network parameter unknown, hash updated": ("shallow-lm", _network_state(
        lambda state: state["params"].update(command="rm -rf /")), "cannot read model part"),
    "training inputs changed": ("bspline", lambda d: (d / "training_inputs.csv").write_text(
        "target\n1\n"), "training_inputs.csv' does not match its sha256"),
}


@pytest.mark.parametrize("case", list(BROKEN))
def test_broken_model_directory_is_one_line_exit_2(model_copy, readings_csv, tmp_path, capsys,
                                                   case):
    name, damage, words = BROKEN[case]
    model_dir = model_copy(name)
    damage(model_dir)
    pred = tmp_path / "pred.csv"
    assert main(["predict", str(model_dir), str(readings_csv), "--out", str(pred)]) == 2
    line = one_error_line(capsys)
    assert words in line, line
    assert not pred.exists()


@pytest.mark.parametrize("command", ["rank", "drift"])
def test_rank_and_drift_refuse_a_tampered_model_in_one_line(model_copy, readings_csv, tmp_path,
                                                            capsys, command):
    model_dir = model_copy("knn")
    plant(model_dir / "estimator.skops", call_node("builtins", "exec", "x = 1"))
    rehash(model_dir)
    out = tmp_path / "report"
    assert main([command, str(readings_csv), "--model", str(model_dir), "--out", str(out)]) == 2
    assert "refusing skops node ConstructorFromReduceNode" in one_error_line(capsys)
    assert not out.exists()


def test_mlflow_model_refuses_a_tampered_directory_in_one_line(model_copy, tmp_path):
    from types import SimpleNamespace

    from models.serving.pyfunc_model import BacklashPredictor

    model_dir = model_copy("bspline")
    _flip_last_byte(model_dir / "estimator.json")
    with pytest.raises(InputError, match="does not match its sha256") as caught:
        BacklashPredictor().load_context(SimpleNamespace(artifacts={"model_dir": str(model_dir)}))
    assert "\n" not in str(caught.value)


def test_intact_directories_load_and_predict_as_saved(trained, readings_csv):
    """The checks refuse only what is wrong: every save format loads back unchanged."""
    from features.table import prediction_inputs

    readings = read_readings(readings_csv, "auto")
    for name, model_dir in trained.items():
        model = registry.load_model(model_dir)
        inputs = prediction_inputs(readings, model.feature_names_)
        saved = pd.read_csv(model_dir / "training_inputs.csv")
        assert model.name == name and list(saved.columns) == model.feature_names_
        original = FITS[name].estimator.predict(inputs[model.feature_names_])
        np.testing.assert_allclose(model.predict(inputs), original, rtol=0, atol=1e-12)
        spec = json.loads((model_dir / "model.json").read_text())["estimator"]
        assert spec["format"] == {"knn": "skops", "bspline": "json", "hybrid": "self",
                                  "shallow-lm": "self"}[name]


def _as_saved_before_grouping(model_dir: Path) -> int:
    """Rewrite every class path of a model directory to the module paths of before models/
    was grouped (``models.estimators.network`` -> ``models.network``): in its JSON files and
    inside its skops archives; returns how many paths were rewritten."""
    from models import MOVED

    count = 0

    def old(text: str) -> str:
        nonlocal count
        for before, now in MOVED.items():
            count += text.count(now + ".")
            text = text.replace(now + ".", before + ".")
        return text

    for path in sorted(model_dir.rglob("*")):
        if path.suffix == ".json":
            path.write_text(old(path.read_text()))
        elif path.suffix == ".skops":
            with zipfile.ZipFile(path) as archive:
                files = {n: archive.read(n) for n in archive.namelist()}
            files["schema.json"] = old(files["schema.json"].decode()).encode()
            buffer = io.BytesIO()
            with zipfile.ZipFile(buffer, "w") as archive:
                for name, data in files.items():
                    archive.writestr(name, data)
            path.write_bytes(buffer.getvalue())
    def rehashed(node, folder: Path):
        if isinstance(node, dict):
            if "sha256" in node and "path" in node:
                node["sha256"] = persistence.digest(folder / node["path"])
            return {k: rehashed(v, folder) for k, v in node.items()}
        return [rehashed(v, folder) for v in node] if isinstance(node, list) else node

    # the sha256 of every rewritten part, the deepest parts first
    for meta in sorted(model_dir.rglob("*.json"), key=lambda p: -len(p.parts)):
        text = meta.read_text()
        if (new := rehashed(json.loads(text), meta.parent)) != json.loads(text):  # the others keep their bytes
            meta.write_text(json.dumps(new))
    return count


@pytest.mark.parametrize("name", ["bspline", "hybrid", "shallow-lm"])
def test_a_model_saved_before_models_was_grouped_still_loads(model_copy, readings_csv, name):
    """A model directory naming its classes by their old module paths loads, and predicts
    what the same model saved now predicts."""
    from features.table import feature_table

    model_dir = model_copy(name)
    assert _as_saved_before_grouping(model_dir) > 0
    assert "models.estimators." not in (model_dir / "model.json").read_text()
    table = feature_table(read_readings(readings_csv, "auto"), target="auto")
    before = registry.load_model(model_dir).predict(table.X)
    now = FITS[name].trained_model().predict(table.X)
    np.testing.assert_allclose(before, now, rtol=0, atol=1e-12)
