"""What every fit of one side needs: its nominal model, its data and signals by role, its settings, where refinements
are kept and how many processes to use (:class:`FitContext`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from sim2real.identification.effects.base import Signals
from sim2real.identification.fitting.data import TorqueData
from sim2real.identification.fitting.nominal import NominalModel, make_signals
from sim2real.identification.fitting.refine import Refinements


@dataclass(frozen=True)
class FitContext:
    """The inputs a rung's fit, a diagnosis's trials and a ceiling share on one side.

    ``nominal``: the nominal model (None where the signals stand for it and no body terms are needed);
    ``fit_signals``/``holdout_signals``: what the judged torque is predicted from on each role's data;
    ``settings``: the fit's settings, merged over :data:`sim2real.identification.fitting.DEFAULT_SETTINGS`;
    ``workers``: processes the fits may use side by side; ``refinements``: where nonlinear refinements are kept
    (None: not kept)."""

    nominal: NominalModel | None
    fit_data: TorqueData
    holdout_data: TorqueData
    fit_signals: Signals
    holdout_signals: Signals
    settings: Mapping[str, Any]
    workers: int = 1
    refinements: Refinements | None = None

    @classmethod
    def on_nominal(cls, nominal: NominalModel, fit_data: TorqueData, holdout_data: TorqueData,
                   settings: Mapping[str, Any], **options: Any) -> FitContext:
        """The context whose signals are the nominal model's on the data (the body side's); ``options``: the other
        fields (``workers``, ``refinements``, or signals of the caller's)."""
        fit_signals = options.pop("fit_signals", None) or make_signals(nominal, fit_data)
        holdout_signals = options.pop("holdout_signals", None) or make_signals(nominal, holdout_data)
        return cls(nominal, fit_data, holdout_data, fit_signals, holdout_signals, settings, **options)

    def with_settings(self, settings: Mapping[str, Any]) -> FitContext:
        return replace(self, settings=settings)
