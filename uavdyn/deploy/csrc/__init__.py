"""C sources shipped with the bundles (package data): the dense QP solver and the MPC."""
