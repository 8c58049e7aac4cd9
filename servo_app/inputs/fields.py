"""Per-field conversion and limits shared by serial and CAN sensors: raw -> scale, offset -> checked."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, model_validator

from servo_app.inputs.errors import KeyedError
from servo_app.inputs.validate import check_range


class FieldConfig(BaseModel):
    # No nan or inf (TOML spells both): a nan scale or limit loaded, then refused every sample at run time.
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    scale: float = 1.0
    offset: float = 0.0
    min: float | None = None  # limits apply to the converted value
    max: float | None = None

    @model_validator(mode="after")
    def _ordered(self) -> FieldConfig:
        if self.min is not None and self.max is not None and self.min > self.max:
            raise KeyedError("min", self.min, f"above max {self.max}")
        return self

    def convert(self, name: str, raw: float) -> float:
        """Scale and check; raises ValueRejected naming the field and the value."""
        return check_range(name, check_range(name, raw) * self.scale + self.offset, self.min, self.max)


DEFAULT_FIELD = FieldConfig()
