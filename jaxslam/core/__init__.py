"""Pure math on batched arrays: sigma points, square-root factors, resampling, SE(2).
No SLAM vocabulary here."""

from jaxslam.core import resampling, se2, sigma, sqrt
from jaxslam.core.resampling import (
    effective_sample_size,
    get_resampler,
    multinomial,
    normalize_log_weights,
    residual,
    selective_resample,
    stratified,
    systematic,
)
from jaxslam.core.sigma import UTParams, UTResult, sigma_points, unscented_transform, ut_moments, ut_weights
from jaxslam.core.sqrt import (
    chol_update,
    chol_update_checked,
    chol_update_many,
    chol_update_many_checked,
    sqrt_ut_moments,
    tria,
)

__all__ = [
    "resampling", "se2", "sigma", "sqrt",
    "effective_sample_size", "get_resampler", "multinomial", "normalize_log_weights",
    "residual", "selective_resample", "stratified", "systematic",
    "UTParams", "UTResult", "sigma_points", "unscented_transform", "ut_moments", "ut_weights",
    "chol_update", "chol_update_checked", "chol_update_many", "chol_update_many_checked",
    "sqrt_ut_moments", "tria",
]
