"""The built wheel, installed into a fresh virtual environment, gives a working granbayes.

What is tested is the package as a user gets it from ``pip install granbayes`` (a wheel):
the wheel is built from a copy of the sources, installed with ``pip install --no-deps``
into a new virtual environment, and ``granbayes`` is run from a folder outside the
repository, so nothing can be found in the source tree by accident.

How the new environment gets the dependencies without downloading them: it is created
empty (``python -m venv --without-pip``) and given one ``.pth`` line with the
site-packages folder of the interpreter running the tests, which already holds every
dependency at the locked versions. ``--system-site-packages`` would not do it: it exposes
the *base* interpreter's packages, not those of the virtual environment the tests run in.
The ``.pth`` line is a plain path, so the ``.pth`` files of that folder (among them the
editable install of the source tree) are not processed and granbayes itself comes only
from the wheel, as the test checks. The wheel is built with ``--no-build-isolation``
(setuptools is in the dev extra) and installed with the test interpreter's pip
(``pip --python``), so no step needs the network.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pandas as pd
import pytest

from granbayes import simulate

#: One module fixture (the installed wheel) for all its tests, so one xdist group (one
#: worker). The fast tests stay clear of compiling the whole kernel in the new
#: environment (~35 s, which no cache of the source tree can spare): a small kernel
#: function stands for it, and the jump runs the installed kernel as plain Python; the
#: slow test compiles it all, runs the demo and a fit.
pytestmark = [pytest.mark.long, pytest.mark.xdist_group("install")]

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "LICENSE", "granbayes")


def _run(
    args: list, cwd: Path, timeout: float = 600, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess:
    proc = subprocess.run(
        [str(a) for a in args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=None if env is None else {**os.environ, **env},
    )
    assert proc.returncode == 0, f"{args} -> {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    return proc


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """(wheel, the new environment's bin folder, a work folder outside the repository)."""
    tmp = tmp_path_factory.mktemp("install")
    src = tmp / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc", "*.egg-info")
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=ignore)
        else:
            shutil.copy2(ROOT / name, src / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input"]
    _run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", tmp / "dist", src], tmp)
    (wheel,) = (tmp / "dist").glob("granbayes-*.whl")

    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], tmp)
    bindir = venv / ("Scripts" if sys.platform == "win32" else "bin")
    python = next(p for p in (bindir / "python", bindir / "python.exe") if p.exists())
    target = Path(
        _run(
            [python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], tmp
        ).stdout.strip()
    )
    deps = {sysconfig.get_path("purelib"), sysconfig.get_path("platlib")}
    (target / "_test_dependencies.pth").write_text("\n".join(sorted(deps)) + "\n")
    _run([*pip, "--python", python, "install", "--no-deps", "--no-index", wheel], tmp)
    work = tmp / "work"
    work.mkdir()
    return wheel, bindir, work


def test_wheel_contents(installed) -> None:
    """The wheel holds the package, the reference data, the licence and the entry point."""
    wheel, _, _ = installed
    names = zipfile.ZipFile(wheel).namelist()
    for name in ("experiment.toml", "jumps.csv", "TRUTH.md", "truth.toml", "README.md"):
        assert f"granbayes/data/reference/{name}" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    assert "granbayes = granbayes._cli:main" in zipfile.ZipFile(wheel).read(entry_points).decode()


def test_installed_package_is_the_wheel(installed) -> None:
    """granbayes and its reference data come from the new environment, not the sources."""
    _, bindir, work = installed
    code = (
        "import json, granbayes\n"
        "from granbayes._cli import REFERENCE_DATA\n"
        "from granbayes import load_experiment, load_jumps\n"
        "t = load_jumps(REFERENCE_DATA, load_experiment(REFERENCE_DATA))\n"
        "print(json.dumps({'file': granbayes.__file__, 'data': str(REFERENCE_DATA),"
        " 'version': granbayes.__version__, 'rows': len(t),"
        " 'synthetic': bool(t['source'].str.startswith('synthetic').all())}))\n"
    )
    info = json.loads(_run([bindir / "python", "-c", code], work).stdout)
    venv = bindir.parent.resolve()
    assert Path(info["file"]).resolve().is_relative_to(venv)
    assert Path(info["data"]).resolve().is_relative_to(venv)
    assert not Path(info["file"]).resolve().is_relative_to(ROOT)
    assert info["rows"] == 250 and info["synthetic"]
    out = _run([bindir / "granbayes", "--version"], work).stdout
    assert out.strip() == f"granbayes {info['version']}"


def test_every_module_imports_and_the_kernel_compiles_where_installed(installed) -> None:
    """Every module of the installed package imports (a subpackage left out of the wheel
    fails here), and numba compiles a kernel function from the installed sources and
    caches it beside them (``cache=True``: the sources must ship and their folder be
    writable). One small function stands for the kernel: the whole kernel takes ~35 s
    to compile in a new environment, the same mechanism (the slow test below runs it)."""
    _, bindir, work = installed
    code = (
        "import importlib, json, pkgutil, granbayes\n"
        "names = [m.name for m in pkgutil.walk_packages(granbayes.__path__, 'granbayes.')]\n"
        "for name in names: importlib.import_module(name)\n"
        "from granbayes import _kernel\n"
        "value = float(_kernel.static_strength(0.01, 3000.0, 2.0e4))\n"
        "print(json.dumps({'modules': names, 'value': value,\n"
        " 'folder': str(__import__('pathlib').Path(_kernel.__file__).parent)}))\n"
    )
    info = json.loads(_run([bindir / "python", "-c", code], work).stdout)
    assert {"granbayes._kernel", "granbayes.stats", "granbayes.testing"} <= set(info["modules"])
    assert len(info["modules"]) > 40
    assert info["value"] == 3000.0 * 0.01 + 2.0e4 * 0.01 * 0.01
    cached = list((Path(info["folder"]) / "__pycache__").glob("_kernel.static_strength-*.nbi"))
    assert Path(info["folder"]).resolve().is_relative_to(bindir.parent.resolve()) and cached


def test_a_jump_from_the_wheel_is_the_sources_jump(installed) -> None:
    """``granbayes simulate`` of one jump from the wheel, run from a folder outside the
    repository: the height the sources compute. The installed kernel runs as plain Python
    here (``NUMBA_DISABLE_JIT=1``, a second): the same code as the compiled kernel, whose
    height it gave to the last bit on the machines of 2026-11-28; the tolerance, 1e-9 mm,
    leaves room for a math library that rounds a last bit otherwise than the compiled
    code's."""
    _, bindir, work = installed
    jump = ["delayed_stutter", 0.612, {"k": 3000.0, "c_d": 50.0, "r_unload": 20.0}]
    params = [a for name, value in jump[2].items() for a in ("--param", f"{name}={value!r}")]
    args = [bindir / "granbayes", "simulate", "--command", jump[0], "--phi", jump[1], *params]
    out = _run([*args, "--json"], work, env={"NUMBA_DISABLE_JIT": "1"})
    result = json.loads(out.stdout)
    assert result["status"] == "ok"
    assert result["height_mm"] == pytest.approx(simulate(*jump).height_mm, rel=0, abs=1e-9)


@pytest.mark.slow
def test_full_demo_and_a_fit_from_the_wheel(installed) -> None:
    """The whole ``granbayes demo`` (the kernel compiled in the new environment, the fit of
    the shipped reference data included, about 4 minutes on 2 cores) and a tiny
    ``granbayes fit`` of a SYNTHETIC folder cut from the shipped reference data, from the
    installed wheel."""
    _, bindir, work = installed
    gb = bindir / "granbayes"
    _run([gb, "demo", "--out", "demo-full"], work, timeout=1800)
    assert (work / "demo-full" / "fit" / "posterior.nc").stat().st_size > 0
    heights = pd.read_csv(work / "demo-full" / "heights.csv")
    assert len(heights) == 5 and (heights["status"] == "ok").all()

    code = (
        "from granbayes._synthetic import REFERENCE_DATA\n"
        "import pandas as pd, shutil, sys\n"
        "shutil.copy(REFERENCE_DATA / 'experiment.toml', 'small/experiment.toml')\n"
        "t = pd.read_csv(REFERENCE_DATA / 'jumps.csv')\n"
        "keep = (t.phi == 0.612) & (t.freq_hz == 12.0) & t.command.isin(['preload', 'stutter'])\n"
        "t[keep].to_csv('small/jumps.csv', index=False)\n"
    )
    (work / "small").mkdir()
    _run([bindir / "python", "-c", code], work)
    _run(
        [gb, "fit", "small", "--out", "fit", "--terms", "depth", "--seed", "1", "--walkers",
         "8", "--ensembles", "2", "--max-steps", "300", "--allow-unconverged", "--quiet",
         "--threads", "1"],
        work,
    )  # fmt: skip
    assert (work / "fit" / "posterior.nc").stat().st_size > 0
    assert "SYNTHETIC" in (work / "fit" / "summary.md").read_text()
