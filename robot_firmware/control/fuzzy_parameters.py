"""The fuzzy scheduler's parameter file: what `swarm tune` writes and robots load (eqs. 6-7).

A file holds, per input, the membership centres (normalised, finite, strictly increasing, 2 to
7 of them: the count sets the number of fuzzy sets and hence the rule count K) and optionally a
rule table; without one, Table 2 restricted to those set counts is used.  Reading a file is
`swarm_config.scenario.load_fuzzy_parameters`.
"""

from __future__ import annotations

import math
from itertools import pairwise

import yaml
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from robot_firmware.control.fuzzy import MAX_SETS, FuzzyRuleBase


class FuzzyParameters(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    error_centres: list[float] = Field(min_length=2, max_length=MAX_SETS)
    rate_centres: list[float] = Field(min_length=2, max_length=MAX_SETS)
    rule_outputs: list[list[float]] | None = None
    """Rows e, columns ė, values ΔK on [-1, 1]; omitted means Table 2."""

    @field_validator("error_centres", "rate_centres")
    @classmethod
    def _increasing(cls, centres: list[float]) -> list[float]:
        if not all(math.isfinite(c) for c in centres):
            raise ValueError("centres must be finite numbers")
        if any(b <= a for a, b in pairwise(centres)):
            raise ValueError("centres must be strictly increasing")
        return centres

    @model_validator(mode="after")
    def _table_shape(self) -> FuzzyParameters:
        if self.rule_outputs is not None:
            rows, cols = len(self.error_centres), len(self.rate_centres)
            if len(self.rule_outputs) != rows or any(len(r) != cols for r in self.rule_outputs):
                raise ValueError(f"rule_outputs must be {rows} rows of {cols} values")
            if any(not -1.0 <= v <= 1.0 for r in self.rule_outputs for v in r):
                raise ValueError("rule outputs must lie in [-1, 1]")
        return self

    def rule_base(self) -> FuzzyRuleBase:
        return FuzzyRuleBase.from_centres(self.error_centres, self.rate_centres, self.rule_outputs)

    @staticmethod
    def table2_defaults() -> FuzzyParameters:
        even = [round(-1.0 + 2.0 * i / (MAX_SETS - 1), 12) for i in range(MAX_SETS)]
        return FuzzyParameters(error_centres=even, rate_centres=list(even))

    def dump_yaml(self) -> str:
        return yaml.safe_dump(self.model_dump(exclude_none=True), sort_keys=False)
