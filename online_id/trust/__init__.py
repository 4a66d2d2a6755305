"""Whether to trust a run and a result: what a run can tell before any estimate (``check``, with the
Cramér-Rao bound of ``identifiability``), whether its signals can be those of a car in SI units and ISO
signs (``plausibility``), and whether an estimate is consistent with the model (``consistency``)."""
