"""The sim-to-real gap diagnosis: ``gap.py`` (where), ``fitting.py`` (model families on block
means), ``diagnose.py`` (which effect, how far, on held-out data)."""
