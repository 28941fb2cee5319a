"""Simulation vs. recording: locate the mismatch, name the missing physics, model it, refit."""

from .catalogue import CATALOGUE, VOCABULARY, implemented
from .data import Observations, estimate_scene, observe
from .model import DiagnosisModel
from .persist import load_model, save_model
from .prediction import Prediction, predict
from .run import Diagnosis, diagnose

__all__ = [
    "CATALOGUE",
    "VOCABULARY",
    "Diagnosis",
    "DiagnosisModel",
    "Observations",
    "Prediction",
    "diagnose",
    "estimate_scene",
    "implemented",
    "load_model",
    "observe",
    "predict",
    "save_model",
]
