"""Performance knobs: the table of every knob (knobs), the per-device tuning files that carry
`clray tune`'s winner into later renders (store), and the tuner itself (tuner, on Kernel Tuner).
docs/tuning.md describes them."""

from clray.knobs import DEFAULT_TUNING, KNOB_TABLE, KNOBS, Knob, Tuning, TuningError

__all__ = ["DEFAULT_TUNING", "KNOBS", "KNOB_TABLE", "Knob", "Tuning", "TuningError"]
