"""Wear history: a store of estimates per gearbox, resume after restarts, trend and forecast."""
