"""Evaluation: image metrics, motion fidelity and the self-transfer protocol of the paper's Table 1."""

from .fidelity import FidelityOptions, motion_fidelity
from .metrics import frame_metrics, on_white
from .report import result_fidelity, run_report
from .self_eval import EVAL_EXTRACT, EVAL_SELF_OUTPUTS, eval_self, self_target
from .silhouette import SilhouetteReport, silhouette_frame

__all__ = ["eval_self", "EVAL_EXTRACT", "EVAL_SELF_OUTPUTS", "self_target", "motion_fidelity", "FidelityOptions",
           "frame_metrics", "on_white", "run_report", "result_fidelity", "SilhouetteReport", "silhouette_frame"]
