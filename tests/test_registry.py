"""The force-term registry is the one place that describes a term.

Adding a term is two edits: its :class:`~granbayes.forces.ForceTerm` entry in
``granbayes.forces.TERMS`` and its physics in the ``GROUND MODEL`` block of
``granbayes/_kernel.py``. These tests prove the first half: a throwaway term registered at
run time (``monkeypatch``, undone after each test), with nothing else edited, is picked up
by every consumer of per-parameter facts: the default priors and their TOML, the prior
checks, the labels of reports and figures, the units of the posterior variables, the
batch-table columns and their allowed values, the model-criticism candidates, the
``granbayes priors`` command, the generated priors table of the docs and the box of the
energy-identity test.

The second half, the kernel block, cannot be exercised without compiling a kernel for the
new term: the compiled row layout (``granbayes._kernel.ROW_FIELDS``) is fixed at import,
so the simulator refuses the throwaway parameter rather than silently dropping it. So does
the independent scipy oracle (``granbayes.testing``), which is written from
docs/physics-model.md and needs the term's physics too before the cross-check tests pass.
"""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest
import xarray as xr

import granbayes
from granbayes import forces, load_batch_table
from granbayes._cli import EXIT_OK, main
from granbayes._criticism import DiagnoseSettings
from granbayes._errors import InputError
from granbayes._fitting import _variable_attrs
from granbayes._priors import NOISE_PARAMETERS, Prior, default_priors, load_priors, priors_toml
from granbayes.figures import param_label
from granbayes.forces import TERMS, DefaultPrior, ForceLaw, ForceTerm, Parameter
from granbayes.report import _prior_posterior_labels
from granbayes.testing import energy_test_box, simulate_height_scipy

DOCS = Path(__file__).resolve().parents[1] / "docs"

#: A term that exists only in these tests: a constant cohesive pull while advancing.
THROWAWAY = ForceTerm(
    "cohesion",
    "f_coh while advancing (a constant cohesive pull; for tests only)",
    (
        Parameter(
            "f_coh",
            "N",
            "cohesive pull",
            absent=0.0,
            lower=0.0,
            upper=100.0,
            typical=(0.0, 2.0),
            label="f_coh [N]",
            prior=DefaultPrior("loguniform", 0.01, 20.0, why="up to twice the robot's weight"),
        ),
    ),
)


@pytest.fixture
def registered(monkeypatch: pytest.MonkeyPatch) -> Parameter:
    """Register :data:`THROWAWAY` for one test; return its parameter."""
    monkeypatch.setitem(TERMS, THROWAWAY.name, THROWAWAY)
    return THROWAWAY.parameters[0]


# ----------------------------------------------------------------------------------------
# every registered parameter is complete


@pytest.mark.parametrize("param", forces.PARAMETERS, ids=forces.PARAMETER_NAMES)
def test_every_parameter_has_bounds_prior_reason_label_and_unit(param: Parameter) -> None:
    """Bounds, realistic range, default prior and its reason, label and unit are all there.

    The default prior is a valid :class:`~granbayes.Prior` in the parameter's unit,
    its support and the realistic range lie inside the hard bounds, and the label names
    the unit (with Unicode superscripts for a power, e.g. ``N/m^2`` -> ``N/m²``).
    """
    assert param.unit, param.name
    assert param.description, param.name
    assert math.isfinite(param.lower) and math.isfinite(param.upper)
    assert param.lower < param.upper
    assert param.absent is None or param.check(param.absent) is None
    prior = default_priors()[param.name]  # a Prior: its family, bounds, mu, sigma checked
    assert (prior.dist, prior.lower, prior.upper) == (
        param.prior.dist,
        param.prior.lower,
        param.prior.upper,
    )
    assert prior.unit == param.unit
    assert prior.why == param.prior.why and prior.why.strip(), f"{param.name}: no reason"
    for value in (*param.typical, prior.lower, prior.upper):
        assert param.check(value) is None or (param.lower_open and value == param.lower)
    assert param.label.strip()
    assert param.label.endswith(f"[{param.unit.replace('^2', '²')}]"), param.label


def test_the_registry_is_the_one_source_of_the_default_priors() -> None:
    """Every force-term default prior is the registry's, then the noise parameters'."""
    priors = default_priors()
    assert list(priors) == [*forces.PARAMETER_NAMES, *NOISE_PARAMETERS]
    for p in forces.PARAMETERS:
        d = p.prior
        assert priors[p.name] == Prior(
            d.dist, d.lower, d.upper, mu=d.mu, sigma=d.sigma, unit=p.unit, why=d.why
        )


# ----------------------------------------------------------------------------------------
# a new entry is all the package needs


def test_registry_functions_see_the_new_term(registered: Parameter) -> None:
    assert forces.parameter_term("f_coh") == "cohesion"
    assert forces.parameter("f_coh") is registered
    assert forces.registered_parameters()[-1] is registered
    assert forces.typical_ranges()["f_coh"] == (0.0, 2.0)
    assert forces.terms_of(["cohesion"]) == ("depth", "cohesion")
    law = ForceLaw.from_params({"k": 3000.0, "f_coh": 1.0})
    assert law.terms == ("depth", "cohesion")
    with pytest.raises(ValueError, match="f_coh must be <= 100"):
        ForceLaw.from_params({"k": 3000.0, "f_coh": 1e3})


def test_default_priors_and_their_toml_see_the_new_term(
    registered: Parameter, tmp_path: Path
) -> None:
    priors = default_priors()
    assert list(priors)[-2:] == ["f_coh", "sigma_mm"]
    assert priors["f_coh"] == Prior(
        "loguniform", 0.01, 20.0, unit="N", why="up to twice the robot's weight"
    )
    text = priors_toml()
    assert "# f_coh [N]: up to twice the robot's weight\n[f_coh]\n" in text
    file = tmp_path / "priors.toml"
    file.write_text(text)
    assert load_priors(file) == priors
    file.write_text("[f_coh]\nupper = 500.0\n")  # above the registry's bound, 100 N
    with pytest.raises(InputError, match="f_coh must be <= 100") as info:
        load_priors(file)
    assert info.value.column == "f_coh"


def test_granbayes_priors_command_sees_the_new_term(
    registered: Parameter, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["priors", "--terms", "cohesion"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "[k]" in out and "[f_coh]" in out and "[sigma_mm]" in out and "[c_d]" not in out


def test_report_labels_see_the_new_term(registered: Parameter) -> None:
    assert param_label("f_coh") == "f_coh [N]"
    dt = xr.DataTree()
    dt.attrs["priors"] = json.dumps({"f_coh": {"dist": "loguniform"}, "k": {"dist": "uniform"}})
    assert _prior_posterior_labels(dt, ["f_coh", "k"]) == {
        "f_coh": "log₁₀ f_coh (f_coh in N)",
        "k": "k [N/m]",
    }


def test_posterior_variable_attributes_see_the_new_term(registered: Parameter) -> None:
    attrs = _variable_attrs(("k", "f_coh"))
    assert attrs["f_coh"] == {"units": "N", "long_name": "cohesive pull"}
    assert attrs["k"] == {"units": "N/m", "long_name": "depth stiffness"}


def test_batch_table_sees_the_new_term(registered: Parameter, tmp_path: Path) -> None:
    """The new column is numeric, checked against the registry's lower bound (0 N)."""
    file = tmp_path / "in.csv"
    file.write_text("command,phi,k,f_coh,note\nsingle,0.6,3000,1.5,a\nsingle,0.6,3000,,b\n")
    table = load_batch_table(file)
    assert table.loc[0, "f_coh"] == 1.5 and math.isnan(table.loc[1, "f_coh"])
    file.write_text("command,phi,k,f_coh\nsingle,0.6,3000,-1\n")
    with pytest.raises(InputError, match=">= 0") as info:
        load_batch_table(file)
    assert (info.value.row, info.value.column) == (1, "f_coh")


def test_model_criticism_candidates_see_the_new_term(registered: Parameter) -> None:
    assert "cohesion" in DiagnoseSettings().candidate_terms(("depth", "drag"))


def test_generated_priors_table_sees_the_new_term(registered: Parameter) -> None:
    spec = importlib.util.spec_from_file_location("docs_generate", DOCS / "generate.py")
    generate = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generate)
    row = "| `f_coh` | `cohesion` | cohesive pull | N | loguniform | 0.01 | 20 |"
    assert row in generate.priors_table()


def test_energy_test_box_sees_the_new_term(registered: Parameter) -> None:
    """The box of tests/test_simulator_physics.py, from the entry alone.

    A dimensional coefficient: its prior's support united with 5 times its realistic range.
    """
    lo, hi = energy_test_box(registered)
    assert (lo, hi) == (0.0, 20.0)
    assert registered.check(lo) is None and registered.check(hi) is None


def test_the_physics_is_still_needed(registered: Parameter) -> None:
    """Without a kernel block (and a fresh import) the term is refused, never ignored."""
    with pytest.raises(KeyError, match="compiled kernel"):
        granbayes.simulate("single", 0.612, {"k": 3000.0, "f_coh": 1.0})
    with pytest.raises(KeyError, match="f_coh"):
        simulate_height_scipy("single", 0.612, {"k": 3000.0, "f_coh": 1.0})


def test_the_registry_is_restored_after_a_test() -> None:
    assert "cohesion" not in TERMS
    assert "f_coh" not in default_priors()


# ----------------------------------------------------------------------------------------
# the command registry: a new command is one entry


def _double_push(s):
    """Two push-off periods back to back (a command that exists only in these tests)."""
    from granbayes.commands import Segment

    push = Segment(s.period, coef=-s.amplitude)
    return (push, Segment(s.period, coef=-s.amplitude)), 1


DOUBLE = granbayes.Command(
    "double_push", "-A cos(w t) twice (for tests only)", "touching", ("delay_ms",), _double_push
)


@pytest.fixture
def double_push(monkeypatch: pytest.MonkeyPatch) -> granbayes.Command:
    """Register :data:`DOUBLE` for one test."""
    from granbayes import commands

    monkeypatch.setitem(commands.COMMANDS, DOUBLE.name, DOUBLE)
    return DOUBLE


def test_a_command_registered_at_run_time_is_simulated_loaded_and_described(
    double_push: granbayes.Command, tmp_path: Path
) -> None:
    """One Command entry: built, simulated, accepted by the loader, named in cells.

    Its own setting (``uses``) tells its cells apart and appears in their description, as
    the delay of the delayed stutter does.
    """
    from granbayes import build_command, commands, load_jumps, simulate, stats

    assert "double_push" in commands.command_names()
    program = build_command("double_push")
    assert program.t_end == pytest.approx(0.2) and program.pushoff_index == 1
    one = simulate("single", 0.612, {"k": 3000.0}).height_mm[0]
    two = simulate("double_push", 0.612, {"k": 3000.0}).height_mm[0]
    assert math.isfinite(two) and two != one
    (tmp_path / "jumps.csv").write_text(
        "phi,command,height_mm,delay_ms\n0.612,double_push,50.0,30\n0.612,single,40.0,\n"
    )
    table = load_jumps(tmp_path)
    assert list(table["command"]) == ["double_push", "single"]
    row = {"command": "double_push", "phi": 0.612, "freq_hz": 10.0, "amplitude_mm": 20.0,
           "delay_ms": 30.0, "mean_residual_mm": 2.0, "z": 1.0}  # fmt: skip
    assert "(10 Hz, 20 mm, 30 ms delay)" in stats.describe_cell(row)
    assert double_push.settings == ("freq_hz", "amplitude_mm", "delay_ms")
    assert double_push.label == "double push"
