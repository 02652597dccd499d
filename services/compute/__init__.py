"""The compute engine: cohort-sized batches of pure work on Dask distributed (`engine.py`)."""
