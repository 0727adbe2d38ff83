"""Learning core: ANFIS (numpy predictor, torch hybrid trainer), Fletcher-Reeves CG, least squares, PSO, Elman.

Modules that import torch (trainer side only): anfis_torch, lse.
Modules that must stay numpy-only (edge side): anfis_numpy, paramset, elman, fr_cg, pso.
"""
