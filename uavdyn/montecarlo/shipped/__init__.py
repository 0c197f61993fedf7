"""Shipped example dispersion files (package data), addressable by name."""
