"""The MCAP data lake: transitions, shards, manifests, the catalog, reading, normalising and validating.

It imports only `schemas` and `common`: generators write into it and training reads from it,
never the other way round (a test enforces it).
"""
