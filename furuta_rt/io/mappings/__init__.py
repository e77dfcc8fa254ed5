"""Shipped CSV column mappings (TOML), read with furuta_rt.io.mapping.load_mapping."""
