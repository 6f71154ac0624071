"""Packaging facts the rest of the project relies on."""

from __future__ import annotations

import subprocess
import sys
from importlib import metadata

from hydra import compose, initialize_config_dir

from data_gen.provenance import CONF_DIR


def test_distribution_pins_cpu_torch_and_has_no_torchvision():
    requirements = metadata.requires("patternshop") or []
    assert "torch==2.13.*" in requirements
    assert not any(r.lower().startswith("torchvision") for r in requirements)


def test_console_script_registered():
    scripts = {ep.name: ep.value for ep in metadata.entry_points(group="console_scripts")}
    assert scripts.get("patternshop") == "patternshop.cli:entry_point"


def test_packages_import_and_synthesis_never_imports_lightning():
    code = (
        "import sys, synthesis, synthesis.mapio, synthesis.points, data_gen, patternshop_nn, export; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('lightning', 'pytorch_lightning', 'torchvision')]; "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_hydra_finds_the_configs():
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        cfg = compose(config_name="examples", overrides=["bits=8"])
    assert cfg.bits == 8 and cfg.logo.width == 384


def test_wheel_ships_configs_as_package_data_not_a_top_level_conf(tmp_path):
    """The wheel holds patternshop/conf/*.yaml and no top-level ``conf`` package (a Hydra project's own would clash)."""
    import zipfile
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path), str(root)],
                   check=True, capture_output=True, text=True)
    names = zipfile.ZipFile(next(tmp_path.glob("patternshop-*.whl"))).namelist()
    assert "patternshop/conf/train.yaml" in names and "patternshop/conf/generation/default.yaml" in names
    assert not [name for name in names if name.startswith("conf/")]
    assert "synthesis/assets/palette.npz" in names and "patternshop_nn/assets/default.onnx" in names
