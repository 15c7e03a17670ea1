"""The fleet view as pure functions on params.yaml / ladder.json content (fast), and campaign files."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim2real.errors import InputError
from sim2real.files import validate
from sim2real.measurements.campaigns import DEFAULT_CAMPAIGN, campaign_names, robot_campaigns, wildcard_pattern
from sim2real.report.fleet import compare_campaigns, fleet_document, identified_values, overlaps, render_fleet_markdown

JOINTS = ["j1", "j2", "j3", "j4"]


def params(friction: dict[str, tuple[float, float, float]], bias: float = 0.0) -> dict:
    """params.yaml content as sysid writes it: values, bootstrap intervals, nonlinear shape values."""
    return {
        "robot": "panda",
        "order": ["coulomb_friction", "torque_bias"],
        "effects": {
            "coulomb_friction": {
                "friction": {j: v for j, (v, _, _) in friction.items()},
                "smoothing_velocity": {j: 0.05 for j in friction},
            },
            "torque_bias": {"bias": {j: bias for j in friction}},
        },
        "intervals": {
            "coulomb_friction": {
                "friction": {j: [lo, hi] for j, (_, lo, hi) in friction.items()},
                # held fixed by the bootstrap: zero width, never evidence of a change
                "smoothing_velocity": {j: [0.05, 0.05] for j in friction},
            },
            "torque_bias": {"bias": {j: [bias - 0.01, bias + 0.01] for j in friction}},
        },
    }


def ladder(rmse: list[float]) -> dict:
    effects = [[], ["coulomb_friction"], ["coulomb_friction", "torque_bias"]][: len(rmse)]
    return {
        "ladder": [{"effects": e, "metrics": {"torque_rmse": {"overall": r}}} for e, r in zip(effects, rmse)],
        "noise_floor": {"torque_rmse": {"overall": 0.03}},
    }


BASE = {"j1": (0.80, 0.78, 0.82), "j2": (0.61, 0.58, 0.64), "j3": (0.40, 0.39, 0.41), "j4": (0.30, 0.28, 0.32)}


def campaign(arm: str, date: str | None, p: dict, name: str | None = None) -> dict:
    name = name or f"{arm}-{date}"
    return {"robot": "panda", "campaign": name, "arm": arm, "date": date,
            "measurements": f"configs/panda/campaigns/{name}.yaml", "report": f"results/panda/{name}/gap.md",
            "ladder": ladder([0.3, 0.06, 0.04]), "params": p}


def test_identified_values_keep_physical_parameters_with_a_width() -> None:
    rows = identified_values(params(BASE, bias=0.1))
    assert {(r["effect"], r["parameter"]) for r in rows} == {("coulomb_friction", "friction"), ("torque_bias", "bias")}
    j2 = next(r for r in rows if r["parameter"] == "friction" and r["joint"] == "j2")
    assert j2 == {"effect": "coulomb_friction", "parameter": "friction", "joint": "j2", "component": None,
                  "unit": "N*m", "value": 0.61, "interval": [0.58, 0.64]}


def test_identified_values_of_vector_and_global_parameters() -> None:
    p = {"effects": {"payload": {"mass": 1.5, "com": [0.0, 0.01, 0.15]}, "actuation_delay": {"delay": 0.02}},
         "intervals": {"payload": {"mass": [1.4, 1.6], "com": [[-0.01, 0.01], [0.0, 0.02], [0.14, 0.16]]},
                       "actuation_delay": {"delay": [0.02, 0.02]}}}
    rows = identified_values(p)
    # delay is a nonlinear parameter: not in the effect's linear parameters, never compared
    assert [(r["parameter"], r["component"]) for r in rows] == [("com", 0), ("com", 1), ("com", 2), ("mass", None)]
    assert rows[2]["interval"] == [0.14, 0.16] and rows[3]["unit"] == "kg"


def test_identified_link_inertias_are_per_link() -> None:
    """link_inertia keeps its values per body under `links` (as sysid writes them), with intervals there."""
    p = {"effects": {"link_inertia": {"base_parameters": 36, "links": {
            "panda_link1": {"mass": 4.97, "com": [0.0039, 0.0021, -0.0476], "inertia": [0.70, 0.0, 0.0, 0.71, 0.02, 0.01]},
            "panda_hand": {"mass": 1.08, "com": [0.0, 0.0, 0.03], "inertia": [0.01, 0.0, 0.0, 0.01, 0.0, 0.002]}}}},
         "intervals": {"link_inertia": {"base_parameters": [36.0, 36.0], "links": {
            "panda_link1": {"mass": [4.97, 4.97], "com": [[0.0039, 0.0039]] * 3, "inertia": [[0.70, 0.70]] * 6},
            "panda_hand": {"mass": [1.02, 1.13], "com": [[-0.01, 0.01], [-0.01, 0.01], [0.02, 0.04]],
                           "inertia": [[0.01, 0.01]] * 6}}}}}
    rows = identified_values(p)
    # link1 did not move (zero-width intervals), base_parameters is not a physical parameter
    assert [(r["joint"], r["parameter"], r["component"]) for r in rows] == [
        ("panda_hand", "com", 0), ("panda_hand", "com", 1), ("panda_hand", "com", 2), ("panda_hand", "mass", None)]
    heavier = dict(p, effects={"link_inertia": {"links": {"panda_hand": {"mass": 1.45, "com": [0.0, 0.0, 0.03]}}}},
                   intervals={"link_inertia": {"links": {"panda_hand": {
                       "mass": [1.40, 1.50], "com": [[-0.01, 0.01], [-0.01, 0.01], [0.02, 0.04]]}}}})
    fleet = fleet_document([campaign("panda_2", "2026-10", p), campaign("panda_2", "2026-11", heavier)])
    (change,) = fleet["arms"][0]["changes"]
    assert change["text"] == ("panda_2: link_inertia.mass on panda_hand rose from 1.08 [1.02, 1.13] to 1.45 "
                              "[1.4, 1.5] kg between 2026-10 and 2026-11")


def test_overlap_is_closed() -> None:
    assert overlaps([0.0, 1.0], [1.0, 2.0])
    assert overlaps([0.5, 0.6], [0.0, 2.0])
    assert not overlaps([0.0, 0.99], [1.0, 2.0])


def test_a_change_counts_only_where_intervals_do_not_overlap() -> None:
    drifted = dict(BASE, j2=(0.83, 0.79, 0.86), j3=(0.42, 0.405, 0.43))  # j3 moved, but within overlap
    changes, compared = compare_campaigns(identified_values(params(BASE)), identified_values(params(drifted)))
    assert compared == 8
    assert [(c["parameter"], c["joint"], c["direction"]) for c in changes] == [("friction", "j2", "rose")]


def test_fleet_names_the_drifted_parameter_in_words() -> None:
    drifted = dict(BASE, j2=(0.83, 0.79, 0.86))
    fleet = fleet_document([
        campaign("panda_2", "2026-11", params(drifted)),
        campaign("panda_2", "2026-10", params(BASE)),  # order of input does not matter: dates order them
        campaign("panda_3", "2026-10", params(BASE)),
        campaign("panda_3", "2026-11", params(BASE)),
    ])
    arms = {a["arm"]: a for a in fleet["arms"]}
    assert [c["date"] for c in arms["panda_2"]["campaigns"]] == ["2026-10", "2026-11"]
    (change,) = arms["panda_2"]["changes"]
    assert change["text"] == (
        "panda_2: coulomb_friction on j2 rose from 0.61 [0.58, 0.64] to 0.83 [0.79, 0.86] N·m between 2026-10 and 2026-11"
    )
    assert arms["panda_3"]["changes"] == [] and arms["panda_3"]["comparisons"][0]["values_compared"] == 8
    assert fleet["summary"] == {"arms": 2, "campaigns": 4, "changes": 1, "drifted_arms": ["panda_2"]}
    md = render_fleet_markdown(fleet, "fleet/parameters.png")
    assert change["text"] in md
    assert "panda_3: no identified value changed between 2026-10 and 2026-11" in md
    assert "| panda_2-2026-10 | 2026-10 | 0.300 | 0.060 | 0.040 | 0.030 |" in md
    assert "| coulomb_friction.friction on j2 | N·m | 0.61 [0.58, 0.64] | 0.83 [0.79, 0.86] |" in md


def test_the_actuator_link_has_its_own_holdout_table() -> None:
    with_link = campaign("panda_2", "2026-11", params(BASE))
    with_link["ladder"] = {**ladder([0.3, 0.06]), "actuator": {
        "ladder": [{"effects": [], "metrics": {"torque_rmse": {"overall": 0.08}}},
                   {"effects": ["actuation_delay"], "metrics": {"torque_rmse": {"overall": 0.021}}}],
        "noise_floor": {"torque_rmse": {"overall": 0.02}}}}
    fleet = fleet_document([campaign("panda_2", "2026-10", params(BASE)), with_link])
    validate(fleet, "fleet.schema.json")
    older, newer = fleet["arms"][0]["campaigns"]
    assert older["actuator_holdout"] is None
    assert [r["label"] for r in newer["actuator_holdout"]["rungs"]] == ["nominal", "+ actuation_delay"]
    md = render_fleet_markdown(fleet)
    assert "| panda_2-2026-11 | 2026-11 | 0.080 | 0.021 | 0.020 |" in md
    assert "actuator link (measured against commanded torque)" in md and "per rung of configs/panda/model.yaml, body link." in md


def test_undated_default_campaign_is_listed_not_compared() -> None:
    fleet = fleet_document([campaign("panda", None, params(BASE), DEFAULT_CAMPAIGN),
                            campaign("panda", "2026-10", params(dict(BASE, j1=(2.0, 1.9, 2.1))))])
    (arm,) = fleet["arms"]
    assert [c["campaign"] for c in arm["campaigns"]] == ["default", "panda-2026-10"]
    assert arm["comparisons"] == [] and arm["changes"] == []
    assert "fewer than two dated campaigns" in render_fleet_markdown(fleet)


def test_two_campaigns_of_one_arm_on_one_date_are_refused() -> None:
    with pytest.raises(InputError, match="campaign/date.*already has a campaign dated 2026-10"):
        fleet_document([campaign("a", "2026-10", params(BASE), "x"), campaign("a", "2026-10", params(BASE), "y")])


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


RUNS = "runs:\n  - {name: fit, path: results/panda/lab/demo/fit.parquet, role: fit}\n"


def test_campaign_files(tmp_path: Path) -> None:
    _write(tmp_path / "panda/measurements.yaml", RUNS)
    _write(tmp_path / "panda/campaigns/panda_2-2026-10.yaml", RUNS + "campaign: {arm: panda_2, date: '2026-10'}\n")
    _write(tmp_path / "panda/campaigns/panda_2-2026-11.yaml", RUNS + "campaign: {arm: panda_2, date: 2026-11-03}\n")
    _write(tmp_path / "panda/campaigns/README.md", "not a campaign")
    assert campaign_names("panda", tmp_path) == ["panda_2-2026-10", "panda_2-2026-11"]
    campaigns = robot_campaigns("panda", tmp_path)
    assert [(c.name, c.arm, c.date, c.prefix) for c in campaigns] == [
        ("default", "panda", None, ""),
        ("panda_2-2026-10", "panda_2", "2026-10", "panda_2-2026-10/"),
        ("panda_2-2026-11", "panda_2", "2026-11-03", "panda_2-2026-11/"),  # an unquoted YAML date is accepted
    ]
    assert campaigns[1].measurements.endswith("panda/campaigns/panda_2-2026-10.yaml")
    assert wildcard_pattern(["b.1", "a"]) == r"(?:(?:a|b\.1)/)?" and wildcard_pattern([]) == "(?:)"


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("sysid", RUNS + "campaign: {date: '2026-10'}\n", r"sysid\.yaml: file name: 'sysid' is reserved"),
        ("2026-10", RUNS, r"2026-10\.yaml: campaign/date: a campaign file needs the date.*Fix: add"),
        ("2026-11", RUNS + "campaign: {date: 'Nov 2026'}\n", r"2026-11\.yaml: key 'campaign/date'"),
    ],
)
def test_bad_campaign_files_name_file_key_and_fix(tmp_path: Path, name: str, text: str, message: str) -> None:
    _write(tmp_path / "panda/campaigns" / f"{name}.yaml", text)
    with pytest.raises(InputError, match=message):
        robot_campaigns("panda", tmp_path)
