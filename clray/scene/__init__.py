"""Scene files -> validated, frozen model."""
