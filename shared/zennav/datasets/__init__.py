"""Loaders and writers of recorded datasets; each returns a zennav.nav.types.Dataset."""
