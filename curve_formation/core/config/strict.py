"""The base of every section of an experiment file's schema: unknown keys refused, numbers
finite.
"""

from pydantic import BaseModel, ConfigDict


Pair = tuple[float, float]


class Strict(BaseModel):
    """Base: unknown keys are errors; numbers are finite (no NaN, no infinity)."""

    model_config = ConfigDict(extra='forbid', strict=False, populate_by_name=True,
                              allow_inf_nan=False)
