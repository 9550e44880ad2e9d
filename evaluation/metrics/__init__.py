"""Accuracy metrics against ground truth: flow and lifetime errors
(:mod:`.flow`), denoising rates and ROC AUC (:mod:`.denoise`), feature-track
error and age (:mod:`.tracks`)."""

from __future__ import annotations

from .denoise import binomial_pass, denoise_rates, noise_passed_by_label, roc_auc
from .flow import flow_errors, lifetime_errors, rotational_flow, simulator_normal_truth
from .tracks import TrackScore, score_tracks, truth_length

__all__ = [
    "flow_errors", "lifetime_errors", "rotational_flow", "simulator_normal_truth",
    "denoise_rates", "noise_passed_by_label", "roc_auc", "binomial_pass",
    "TrackScore", "score_tracks", "truth_length",
]
