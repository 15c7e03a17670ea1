"""Every word of the diagnosis: verdicts, notes, caveats, skipped trials, the model-free ceiling's reading, what the
sides can tell apart, written once from the typed data of :mod:`sim2real.identification`.

The identification returns data (:class:`~sim2real.identification.diagnosis.Diagnosis`, its notes
:class:`~sim2real.identification.records.Note` records; ladder.json holds their documents); :func:`worded` gives
that document with its words, what gap.json holds and gap.md reads. A new rule of the loop is a new
:class:`~sim2real.identification.records.NoteKind` and one renderer in :data:`NOTE_TEXT`.

One module per subject:

* :mod:`~sim2real.report.verdicts.names`: how the sides, a body's bounds and the separating runs are named;
* :mod:`~sim2real.report.verdicts.headline`: the headline of each status, and the verdict it heads;
* :mod:`~sim2real.report.verdicts.notes`: the notes a verdict carries, one renderer per note kind;
* :mod:`~sim2real.report.verdicts.skipped` and :mod:`~sim2real.report.verdicts.rungs`: why a candidate was not
  tried, and a rung's notes;
* :mod:`~sim2real.report.verdicts.ceiling`: the model-free ceiling's reading;
* :mod:`~sim2real.report.verdicts.sides`: what the sides can tell apart;
* :mod:`~sim2real.report.verdicts.documents`: gap.json's worded sections (:func:`worded`);
* :mod:`~sim2real.report.verdicts.first_screen`, :mod:`~sim2real.report.verdicts.noise_floor` and
  :mod:`~sim2real.report.verdicts.not_judged`: gap.md's first verdict, its noise floor, the joints it does not judge.
"""

from sim2real.report.verdicts.ceiling import (
    DECLARE_ADVICE, FEATURE_TEXT, GAIN_REGIME_TEXT, KIND_TEXT, OFFSET_ADVICE, ceiling_section, ceiling_text,
    feature_text,
)
from sim2real.report.verdicts.documents import DATA_ONLY, diagnosis_section, worded
from sim2real.report.verdicts.first_screen import FOLLOWS_TEXT, LEFT_TEXT, first_screen_verdict, left_text
from sim2real.report.verdicts.headline import HEADLINE, LOOK_AT_WINDOWS, verdict
from sim2real.report.verdicts.names import BOUND_TEXT, SIDE_NAME, SIDE_TEXT, bounds_text, separating_runs
from sim2real.report.verdicts.noise_floor import FLOOR_METHOD_TEXT, floor_sentences
from sim2real.report.verdicts.not_judged import not_judged_text
from sim2real.report.verdicts.notes import NEAR_FIGURE_TEXT, NOTE_KEYS, NOTE_TEXT, implausible_text, near_text, trouble_text
from sim2real.report.verdicts.rungs import PRIOR_BOUND_TEXT, PRIOR_GRID_TEXT, chosen_by_text, rung_note, violations_text
from sim2real.report.verdicts.sides import MODE_TEXT, judged_text, sides_section
from sim2real.report.verdicts.skipped import SKIP_TEXT, skip_reason

__all__ = [
    "BOUND_TEXT", "DATA_ONLY", "DECLARE_ADVICE", "FEATURE_TEXT", "FLOOR_METHOD_TEXT", "FOLLOWS_TEXT", "GAIN_REGIME_TEXT",
    "HEADLINE", "KIND_TEXT", "LEFT_TEXT", "LOOK_AT_WINDOWS", "MODE_TEXT", "NEAR_FIGURE_TEXT", "NOTE_KEYS", "NOTE_TEXT",
    "OFFSET_ADVICE", "PRIOR_BOUND_TEXT", "PRIOR_GRID_TEXT", "SIDE_NAME", "SIDE_TEXT", "SKIP_TEXT", "bounds_text",
    "ceiling_section", "ceiling_text", "chosen_by_text", "diagnosis_section", "feature_text", "first_screen_verdict",
    "floor_sentences", "implausible_text", "judged_text", "left_text", "near_text", "not_judged_text", "rung_note",
    "separating_runs", "sides_section", "skip_reason", "trouble_text", "verdict", "violations_text", "worded",
]
