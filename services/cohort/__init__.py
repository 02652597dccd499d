"""The simulated cohort shared by `nod cohort`, `nod calibrate-cohort` and `nod analyze power`.

`person`: the default simulated person (the traits fitted to the paper, shipped in `paper/`);
`outcomes`: a cohort's outcomes computed on the engine, their per-trial shares and Fig 8b flows,
and their distance to the paper's tables.
"""
