"""The documents in docs/ stay in step with the shared contracts and with the code.

``docs/data-format.md`` and ``docs/physics-model.md`` begin with the contracts of
``shared/`` (beside the repository) reproduced unchanged; those checks read ``shared/``
through the ``shared_file`` fixture (``tests/conftest.py``: they fail if a contract file is
missing there, and skip, saying so, only in a clone without ``shared/``). The generated
blocks (the command-line reference, the table of default priors) must be what
``python docs/generate.py`` writes today.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import re
from pathlib import Path

from granbayes import _criticism as criticism
from granbayes import stats
from granbayes._cli import SUBCOMMANDS
from granbayes._priors import load_priors

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
ADDITIONS = "\n---\n\n# Additions made in granbayes\n"


def _generator():
    spec = importlib.util.spec_from_file_location("docs_generate", DOCS / "generate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_generated_blocks_are_up_to_date() -> None:
    """The CLI reference and the priors table are what the code gives today."""
    for path, text in _generator().render().items():
        assert path.read_text(encoding="utf-8") == text, (
            f"{path.relative_to(ROOT)} is stale: run `python docs/generate.py`"
        )


def test_data_format_begins_with_the_shared_contract(shared_file) -> None:
    """docs/data-format.md = shared/data-format.md unchanged, then the additions."""
    shared = shared_file("data-format.md").read_text(encoding="utf-8")
    head, sep, _ = (DOCS / "data-format.md").read_text(encoding="utf-8").partition(ADDITIONS)
    assert sep and head.rstrip("\n") == shared.rstrip("\n")


def test_physics_model_sections_1_to_7_are_the_shared_contract(shared_file) -> None:
    """docs/physics-model.md sections 1-7 = shared/physics-model.md unchanged."""
    shared = shared_file("physics-model.md").read_text(encoding="utf-8")
    text = (DOCS / "physics-model.md").read_text(encoding="utf-8")
    head, sep, _ = text.partition(ADDITIONS)
    assert sep, "docs/physics-model.md has no '# Additions made in granbayes' part"
    assert head.rstrip("\n") == shared.rstrip("\n")
    assert re.findall(r"^## (\d+)\.", head, flags=re.M) == [str(i) for i in range(1, 8)]


def test_every_subcommand_is_documented() -> None:
    """Each subcommand has its section (its --help) in docs/data-format.md."""
    text = (DOCS / "data-format.md").read_text(encoding="utf-8")
    for cmd in SUBCOMMANDS:
        assert f"### `granbayes {cmd.name}`" in text, cmd.name
    for code in range(6):
        if code != 1:
            assert f"| {code} |" in text


def _record_keys() -> set[str]:
    """Every key the typed diagnosis record writes: the JSON keys of its dataclasses."""
    from granbayes._criticism import _record

    keys = {"all_converged", "versions", "machine"}
    for record in (
        _record.CellResult,
        _record.CellChange,
        _record.Tie,
        _record.FitRecord,
        _record.BaselineResult,
        _record.SelectedResult,
        _record.RuleRecord,
        _record.DiagnosisRecord,
    ):
        keys |= {f.name for f in dataclasses.fields(record)} - {"key", "environment"}
    return keys


def test_diagnosis_fields_are_documented() -> None:
    """Every field granbayes writes into diagnosis.json is named in docs/data-format.md."""
    text = (DOCS / "data-format.md").read_text(encoding="utf-8")
    dummy = {f.name: 0 for f in dataclasses.fields(criticism.Candidate)} | {"added": ()}
    dummy["estimate"] = criticism.Estimate.PSIS
    candidate = criticism.Candidate(**dummy).to_json()
    keys = _record_keys() | set(candidate) | set(stats.CELL_KEYS)
    # named in code style (`key`, `a.key`, `key[]`) or as a JSON key of the contract ("key")
    missing = sorted(k for k in keys if not re.search(rf"[`\".]{k}[`\"\[]", text))
    assert not missing, f"diagnosis.json fields not in docs/data-format.md: {missing}"


def test_priors_toml_example_loads(tmp_path: Path) -> None:
    """The example of docs/priors.md is a valid priors file and means what it says."""
    text = (DOCS / "priors.md").read_text(encoding="utf-8")
    example = re.search(r"```toml\n(.*?)```", text, flags=re.S).group(1)
    (tmp_path / "priors.toml").write_text(example)
    priors = load_priors(tmp_path / "priors.toml")
    assert (priors["k"].dist, priors["k"].lower, priors["k"].upper) == ("loguniform", 500, 2e4)
    assert (priors["c_d"].dist, priors["c_d"].mu, priors["c_d"].sigma) == ("normal", 20, 10)
    assert priors["sigma_mm"] == load_priors(tmp_path / "priors.toml")["sigma_mm"]


def test_readme_layout_table_lists_every_module() -> None:
    """The README's package-layout table names every module of the package, and no other."""
    text = (DOCS.parent / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Package layout") : text.index("## Reproducibility")]
    table = "\n".join(line for line in section.splitlines() if line.startswith("| `"))
    listed = set(re.findall(r"`(\w+)\.py`", table)) | set(re.findall(r"`(\w+)/`", table))
    package = DOCS.parent / "granbayes"
    modules = {p.stem for p in package.glob("*.py")} - {"__init__"}
    modules |= {p.parent.name for p in package.glob("*/__init__.py")}
    assert listed == modules, (sorted(modules - listed), sorted(listed - modules))
