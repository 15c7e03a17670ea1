"""Each key of a ladder.json rung, of an effect's residual signature and of gap.json's top level is spelled in the
module of the typed row that writes and reads it, and nowhere else in src/ or scripts/: the readers read attributes.

The keys are taken from the rows themselves (every optional part filled in). A key whose word is also a key of another
document, or of another level of these (``effects`` of model.yaml, ``torque_rmse`` of gap.json's own metrics, ...), is
listed in SHARED_WORDS; the test checks that the list is exactly the keys spelled elsewhere, so that a reader spelling
a rung's or the report's own key, or a word newly shared, fails here."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np

from sim2real.identification.diagnosis.result import CandidateEvidence
from sim2real.identification.effects import EFFECTS, Signature
from sim2real.identification.effects.base import Signals
from sim2real.identification.ladder_rows import Rung, RungMetrics
from sim2real.report.gap_document import GapReport, LinkSection

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted([*(ROOT / "src" / "sim2real").rglob("*.py"), *(ROOT / "scripts").glob("*.py")])
LADDER_ROWS = "src/sim2real/identification/ladder_rows.py"
CANDIDATE_ROW = "src/sim2real/identification/diagnosis/result.py"
GAP_DOCUMENT = "src/sim2real/report/gap_document.py"

# The words that are keys of these rows and of other documents or levels too (where else, in brackets).
SHARED_WORDS = {
    "effects",  # model.yaml, params.yaml, the lab's scenarios, gap.json's metrics.model, a note's figures
    "params",  # the fleet's inputs (a params.yaml's path)
    "intervals",  # params.yaml
    "notes",  # a run's metadata, params.yaml, a diagnosis
    "torque_rmse",  # gap.json's metrics, runs[] and noise_floor, ladder.json's noise_floor, the fleet's rungs
    "position_rmse",  # gap.json's metrics and its state domain
    "robot", "joints", "runs", "noise_floor",  # ladder.json, params.yaml, the measurement list, the lab, excitation
    "ladder", "diagnosis", "actuator", "links",  # ladder.json's sections (gap.json words them), model.yaml, sides
    "nominal",  # the nominal rung's name, the nominal model's values in dr/
    "judged",  # a diagnosis's per-joint row
}


def _string_literals(path: Path) -> set[str]:
    """The strings a module's code spells (its docstrings left out)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstrings = {id(node.value) for node in ast.walk(tree)
                  if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)}
    return {node.value for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings}


def _owned_keys() -> dict[str, set[str]]:
    """Each key of the rows, with the modules of the rows that hold it (``metrics``: a rung's and gap.json's)."""
    figures = {"overall": 1.0, "per_joint": {"j1": 1.0}}
    rung = Rung(("viscous_friction",), RungMetrics(figures, figures, figures, figures, figures),
                {"viscous_friction": {}}, {"viscous_friction": {}}, {"status": "optimal"}, ("a note",))
    link = LinkSection((rung,), {"torque_rmse": figures}, "judged", {"status": "at_noise_floor"})
    gap = GapReport("panda", ("j1",), {"torque_rmse": figures}, {}, (), {}, {}, {}, (rung,), {}, link, {})
    owned: dict[str, set[str]] = {}
    for module, keys in ((LADDER_ROWS, [*rung.as_document(), *rung.metrics.as_document()]),
                         (GAP_DOCUMENT, [*gap.as_document(), *link.as_document()]),
                         (CANDIDATE_ROW, ["signature", "statistic"])):
        for key in keys:
            owned.setdefault(key, set()).add(module)
    return owned


def test_each_key_of_the_ladders_rungs_the_signatures_and_the_gap_report_is_spelled_by_its_row_alone():
    owned = _owned_keys()
    assert {"torque_x_floor", "consistency", "metrics", "where", "not_judged"} <= set(owned), "the rows hold their keys"
    spelled = {path.relative_to(ROOT).as_posix(): _string_literals(path) for path in SOURCES}
    assert owned.keys() <= spelled[LADDER_ROWS] | spelled[GAP_DOCUMENT] | spelled[CANDIDATE_ROW]
    elsewhere = {key: sorted(module for module, words in spelled.items() if key in words and module not in owners)
                 for key, owners in owned.items()}
    unshared = {key: modules for key, modules in elsewhere.items() if modules and key not in SHARED_WORDS}
    assert not unshared, f"keys of a row spelled outside it (read the row's attribute): {unshared}"
    assert {key for key, modules in elsewhere.items() if modules} == SHARED_WORDS & set(owned), (
        "SHARED_WORDS lists a word no other module spells any more: take it out")


def test_an_effects_signature_is_typed_and_the_candidate_row_writes_its_keys():
    """Every effect returns a :class:`Signature` (the candidate row writes ``signature``, ``statistic``, ``per_joint``
    and ``lag_s`` from it); no effect module spells those keys."""
    rng = np.random.default_rng(0)
    n, joints = 200, ["j1", "j2"]
    motion = {name: rng.standard_normal((n, 2)) for name in ("q", "qd", "qdd", "tau_nominal")}
    signals = Signals(joint_names=joints, time=np.arange(n) * 0.01, segments=[slice(0, n)], **motion)
    for name in ("viscous_friction", "coulomb_friction", "torque_bias", "torque_gain"):
        signature = EFFECTS[name].evidence(rng.standard_normal((n, 2)), signals)
        assert isinstance(signature, Signature) and signature.description == EFFECTS[name].signature
        assert list(signature.per_joint) == joints and signature.lag_s is None
    effects = sorted((ROOT / "src" / "sim2real" / "identification" / "effects").glob("*.py"))
    assert not any({"signature", "statistic", "per_joint", "lag_s"} & _string_literals(path) for path in effects)
    assert {"signature", "statistic"} <= set(CandidateEvidence.__dataclass_fields__)
