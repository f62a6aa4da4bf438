"""Applications on runs and bags: comparison with a reference, replay, the report, plots."""
