"""The front end as one run: per-frame fusion → segmentation → features → semantic map, cached."""
