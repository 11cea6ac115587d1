"""`clray tune`: the tuner itself (tuner, on Kernel Tuner), its command and its report. The knob
table is clray.knobs and the per-device tuning files that carry the winner into later renders
are clray.device.tuning_files; docs/tuning.md describes them."""

from clray.knobs import DEFAULT_TUNING, KNOB_TABLE, KNOBS, Knob, Tuning, TuningError

__all__ = ["DEFAULT_TUNING", "KNOBS", "KNOB_TABLE", "Knob", "Tuning", "TuningError"]
