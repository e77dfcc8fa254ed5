"""Shipped rig configurations (TOML)."""
