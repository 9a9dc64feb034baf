"""Dataset generation and the MCAP data lake (smgen)."""
