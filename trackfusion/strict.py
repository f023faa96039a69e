"""The one strict base class of the configuration models (pipeline, scenario, sensor and track sections).

Unknown keys are refused (a misspelt key is an error, not a silent default), instances are
frozen (a validated config cannot drift), and NaN / infinity are refused in every float field;
a field where infinity means something (a straight end's ``radius_m: .inf``) says so with
``Field(allow_inf_nan=True)``.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class StrictModel(BaseModel):
    """A pydantic model with ``extra="forbid"``, ``frozen=True``, ``allow_inf_nan=False``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
