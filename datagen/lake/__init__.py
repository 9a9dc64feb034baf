"""The MCAP data lake: shards, manifests, the catalog, reading and validation."""
