"""`morphmimic references`: the retargeted reference's figures over the evaluation's shapes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest


def test_the_survey_compares_root_height_rules_on_the_evaluation_shapes(tmp_path: Path, capsys) -> None:
    from learner.evaluation.shape import reference_survey

    out = tmp_path / "refs"
    assert reference_survey.main(["--preset", "lower_biped", "--shapes", "3", "--rules", "contact_set", "contact_smooth",
                                  "--clearances", "0", "0.01", "--out", str(out)]) == 0
    rows = {(r["rule"], r["clearance_m"]): r for r in json.loads((out / "references.json").read_text())}
    assert len(rows) == 4
    # the third evaluation shape has unequal legs: contact_set jumps by 20 cm, contact_smooth does not
    assert rows[("contact_set", 0.0)]["root_step_mm_max"] > 100.0
    assert rows[("contact_smooth", 0.0)]["root_step_mm_max"] < 0.5 / 60 * 1e3 + 10.0
    # contact_set never lets a stance foot float; the clearance lift keeps every body 1 cm up
    assert rows[("contact_set", 0.0)]["stance_foot_mm_max"] < 5.0
    for rule in ("contact_set", "contact_smooth"):
        assert rows[(rule, 0.01)]["clearance_mm_min"] >= 10.0 - 1e-6
    assert "| contact_smooth | 10 mm |" in (out / "references.md").read_text()
    assert "root step" in capsys.readouterr().out


@pytest.mark.parametrize("argv, says", [
    (["--clearances", "0.5"], "--clearances = (0.5,) is not allowed: give each a finite number in [0, 0.1]"),
    (["--rules", "stilts"], "invalid choice 'stilts' for argument '--rules'"),
    (["--preset", "fish"], "invalid choice 'fish' for argument '--preset'"),
    (["--shapes", "0"], "--shapes = 0 is not allowed: give an integer >= 1"),
])
def test_bad_arguments_are_usage_errors(argv, says, capsys) -> None:
    from learner.evaluation.shape import reference_survey

    with pytest.raises(SystemExit) as exc:
        reference_survey.main(argv)
    assert exc.value.code == 2
    assert says in capsys.readouterr().err
