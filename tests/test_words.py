"""The diagnosis is data, and its words are written once (issue 61): ``diagnose`` returns a typed
:class:`~sim2real.identification.diagnosis.Diagnosis`, its notes records; :mod:`sim2real.report.verdicts` alone words
it; nothing in ``identification/`` assembles a sentence of a verdict, and there "link" names a rigid body only (the
body/drive split is a side, a sensor's placement link_side/motor_side)."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from sysid_synthetic import PANDA_JOINTS, PANDA_URDF, make_run
from sim2real.identification import fitting
from sim2real.identification.diagnosis import Diagnosis, diagnose
from sim2real.identification.records import Note, NoteKind, Side, Status
from sim2real.report.verdicts import NOTE_TEXT, verdict, worded

SOURCE = Path(__file__).resolve().parents[1] / "src" / "sim2real"
IDENTIFICATION = SOURCE / "identification"
VERDICTS = SOURCE / "report" / "verdicts"  # the package that words the diagnosis, one module per subject
# Calls whose words are an error's or a log's, not a verdict's.
ERROR_CALLS = {"InputError", "ValueError", "RuntimeError", "TypeError", "KeyError", "InfeasibleFit", "info", "warning",
               "debug", "error"}
# Where the identification's documents keep labels of their values (an effect's signature and its statistics, a
# body's reasons for being implausible, how a prior's weight was chosen): data's names, not a verdict's sentences.
LABELS = {"effects", "inertial"}


def assembled_sentences(source: str) -> list[tuple[int, str]]:
    """The f-strings of ``source`` holding three words or more outside an error or a log: sentences assembled."""
    tree = ast.parse(source)
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}

    def excused(node: ast.AST) -> bool:
        while node in parents:
            node = parents[node]
            if isinstance(node, ast.Raise):
                return True
            if isinstance(node, ast.Call):
                name = getattr(node.func, "id", None) or getattr(node.func, "attr", "")
                if name in ERROR_CALLS:
                    return True
        return False

    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):
            words = " ".join(str(v.value) for v in node.values if isinstance(v, ast.Constant))
            if len(words.split()) >= 3 and not excused(node):
                out.append((node.lineno, words))
    return out


def test_the_sentence_checker_sees_a_sentence_and_excuses_an_error():
    assert assembled_sentences('verdict = f"On {side}, the model is missing {effect}."')
    assert not assembled_sentences('raise InputError(path, "x", f"the line {name} is listed twice", "fix")')
    assert not assembled_sentences('label = f"{name}"')


def test_nothing_in_identification_assembles_a_sentence_of_a_verdict():
    found = [f"{path.relative_to(SOURCE)}:{line}: {words!r}"
             for path in sorted(IDENTIFICATION.rglob("*.py")) if path.relative_to(IDENTIFICATION).parts[0] not in LABELS
             for line, words in assembled_sentences(path.read_text(encoding="utf-8"))]
    assert not found, "sentences assembled in identification/ (words belong in sim2real.report.verdicts):\n" + \
        "\n".join(found)
    for path in SOURCE.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        assert 'verdict"] +=' not in text and '["verdict"].replace(' not in text, path


def test_link_names_a_rigid_body_only_in_identification():
    """Identifiers: a URDF link, its inertia, the bodies' links, a link-side sensor; never the body/drive split."""
    allowed = {"link", "links", "link_own", "urdf_links", "LinkInertia", "_urdf_link_parameters", "body_links",
               "link_side", "LINK_SIDE"}
    split_words = ("actuator link", "body link", "both links", "each link", "other link", "two links", "one link")
    found = []
    for path in sorted(IDENTIFICATION.rglob("*.py")):
        source = path.read_text(encoding="utf-8")
        found += [f"{path.relative_to(SOURCE)}: '{phrase}'" for phrase in split_words if phrase in source.lower()]
        for node in ast.walk(ast.parse(source)):
            name = (getattr(node, "id", None) or getattr(node, "attr", None) or getattr(node, "arg", None)
                    or (node.name if isinstance(node, (ast.FunctionDef, ast.ClassDef)) else None))
            if isinstance(name, str) and "link" in name.lower() and name not in allowed:
                found.append(f"{path.relative_to(SOURCE)}:{node.lineno}: {name}")
    assert not found, "\n".join(found)


@pytest.fixture(scope="module")
def friction_diagnosis() -> tuple[Diagnosis, fitting.FitContext]:
    """A diagnosis of the nominal model on a Panda whose joints all hide a Coulomb friction (6 s runs)."""
    nominal = fitting.load_nominal(PANDA_URDF, PANDA_JOINTS, {"panda_joint*": 0.1}, "panda_link8")
    hidden = {"coulomb_friction": [0.6] * 7}
    fit_data, holdout_data = [fitting.stack_runs([make_run(name, hidden, seed, duration=6.0, noise=0.01)],
                                                 PANDA_JOINTS, 100.0) for name, seed in (("fit", 3), ("holdout", 4))]
    settings = {**fitting.DEFAULT_SETTINGS, "fit_rate_hz": 100.0, "bootstrap_replicates": 0,
                "refine_max_samples": 1500}
    context = fitting.FitContext.on_nominal(nominal, fit_data, holdout_data, settings)
    current = fitting.fit([], nominal, fit_data, settings, uncertainty=False)
    residual = holdout_data.tau - fitting.predict(current, nominal, holdout_data)
    diagnosis = diagnose([], context, residual, current=current,
                         candidates=["coulomb_friction", "viscous_friction", "payload", "actuation_delay"])
    return diagnosis, context


def test_diagnose_returns_data_and_the_report_alone_words_it(friction_diagnosis):
    diagnosis, _ = friction_diagnosis
    assert isinstance(diagnosis, Diagnosis) and isinstance(diagnosis.status, Status)
    assert diagnosis.status == Status.ADD_EFFECT and diagnosis.best.effect == "coulomb_friction"
    assert diagnosis.side == Side.BODY and all(isinstance(n, Note) for n in (*diagnosis.notes, *diagnosis.skipped))
    skipped = {n.effect: n.kind for n in diagnosis.skipped}
    assert skipped["actuation_delay"] == NoteKind.DRIVE_BEHIND_SENSOR  # a command's effect: the torque is a sensor's
    document = json.loads(json.dumps(diagnosis.as_document()))
    assert "verdict" not in document and not any(key.endswith("_note") for key in document), sorted(document)
    # the document read back is the same data, worded the same
    again = Diagnosis.from_document(document)
    assert verdict(again, "panda") == verdict(diagnosis, "panda")
    assert verdict(diagnosis, "panda").startswith("On the body link (measured torque against the motion), the model "
                                                  "is missing coulomb_friction")
    assert "configs/panda/model.yaml" in verdict(diagnosis, "panda")
    gap = worded({"diagnosis": document}, "panda")["diagnosis"]
    assert gap["verdict"] == verdict(diagnosis, "panda")
    assert {s["effect"]: s["reason"] for s in gap["skipped"]}["actuation_delay"].startswith("an effect of the actuator")


def test_a_new_rule_is_a_note_kind_with_one_renderer():
    """Every note kind a verdict carries has its renderer; none other writes verdict words."""
    verdict_kinds = {NoteKind.LAG_SHAPES, NoteKind.CONFOUNDED, NoteKind.TIED, NoteKind.CAUTION, NoteKind.FAILED_TRIALS,
                     NoteKind.DRIVE_PLACEMENT, NoteKind.SENSOR_LAG, NoteKind.SENSOR_LAG_TRIAL, NoteKind.OTHER_SIDE,
                     NoteKind.HELD_ON_OTHER_SIDE, NoteKind.RELABELLED, NoteKind.NEAR_THRESHOLD, NoteKind.RAISES}
    assert set(NOTE_TEXT) == verdict_kinds
    assert (VERDICTS / "__init__.py").is_file() and "def verdict(" in (VERDICTS / "headline.py").read_text()
    outside = [path for path in SOURCE.rglob("*.py") if not path.is_relative_to(VERDICTS)
               and ("NOTE_TEXT" in path.read_text(encoding="utf-8") or "def verdict(" in path.read_text(encoding="utf-8"))]
    assert not outside, outside
