"""How laws over the current were found: :class:`LawReport`."""

from __future__ import annotations

import dataclasses
from typing import Any


@dataclasses.dataclass(frozen=True)
class LawReport:
    """How laws were found (`GeneralizedModel.report`).

    **Fields:** `law_choice` how the forms were chosen (`"given"`, `"auto"` by the lowest BIC
    of the per-test values, `"fixed"`); `law_criteria` {parameter: {form: BIC}} where the data
    chose; `two_step_rms` [N] the two-step laws' total RMS (NaN if not computed);
    `fell_back_to_two_step` where the joint fit did not improve on them and they were kept;
    `weighting_note` why the two-step weighting fell back to equal weights; `lag_mode`
    (`"none"`, `"fit"`, `"fixed"`); `notes` on the fit (the lag without a varying command,
    the z scale chosen); `timings` [s] per stage; `outcome` the engine's
    :class:`mrjax.engine.Outcome` of the joint fit (its swarm, start, polish stages), or None.
    """

    law_choice: str = "given"
    law_criteria: dict[str, dict[str, float]] | None = None
    two_step_rms: float = float("nan")
    fell_back_to_two_step: bool = False
    weighting_note: str = ""
    lag_mode: str = "none"
    notes: tuple[str, ...] = ()
    timings: dict[str, float] = dataclasses.field(default_factory=dict)
    outcome: Any = None

    @property
    def lag_fitted(self) -> bool:
        """Whether the command filter's rate was fitted."""
        return self.lag_mode == "fit"

    @property
    def polish_steps(self) -> tuple[int, ...]:
        """Levenberg-Marquardt steps of each polish stage of the joint fit."""
        out = self.outcome
        return () if out is None else tuple(int(st.steps[0]) for st in out.stages)
