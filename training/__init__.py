"""Offline tooling: datasets, KNODE training, evaluation and figures (torch, matplotlib)."""
