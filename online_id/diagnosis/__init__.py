"""The sim-to-real gap diagnosis: ``gap.py`` (where), ``fitting.py`` (model families on block
means), ``diagnose.py`` (which effect, how far, on held-out data), ``carry.py`` (the named effects as the
``--effect`` flags that carry them into the estimate, and ``--effects-from``)."""

#: An effect is significant when it lowers the training BIC by more than MIN_BIC_DROP and the
#: held-out cost by at least MIN_REDUCTION (a fraction).
MIN_BIC_DROP = 10.0
MIN_REDUCTION = 0.05

