"""Pure math on batched arrays: sigma points, square-root factors, resampling, SE(2),
NaN-safe numerics. No SLAM vocabulary here."""

from jaxslam.core import numerics, resampling, se2, sigma, sqrt
from jaxslam.core.numerics import safe_atan2, safe_divide, safe_norm, safe_sqrt
from jaxslam.core.resampling import (
    effective_sample_size,
    get_resampler,
    log_likelihood_increment,
    multinomial,
    normalize_log_weights,
    residual,
    selective_resample,
    stratified,
    systematic,
    systematic_rows,
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
    "numerics", "resampling", "se2", "sigma", "sqrt",
    "safe_atan2", "safe_divide", "safe_norm", "safe_sqrt",
    "effective_sample_size", "get_resampler", "log_likelihood_increment", "multinomial", "normalize_log_weights",
    "residual", "selective_resample", "stratified", "systematic", "systematic_rows",
    "UTParams", "UTResult", "sigma_points", "unscented_transform", "ut_moments", "ut_weights",
    "chol_update", "chol_update_checked", "chol_update_many", "chol_update_many_checked",
    "sqrt_ut_moments", "tria",
]
