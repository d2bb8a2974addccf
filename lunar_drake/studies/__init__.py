"""Studies: slip-vs-slope, trade sweeps (drive Drake diagrams; pure metrics live beside them)."""
