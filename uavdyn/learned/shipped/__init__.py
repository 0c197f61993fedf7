"""Shipped correction weights and their loss histories (package data; see README.md)."""
