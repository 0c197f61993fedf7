"""Shipped dataset recipes and their reference value fingerprints (package data)."""
