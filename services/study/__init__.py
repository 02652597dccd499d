"""Study management: the study file, its counterbalanced roster, consent, and `nod study`."""
