# SPDX-License-Identifier: Apache-2.0
"""
Smeared stars: the smear a body rate predicts, and the streak model's fits.

smear (SmearModel: where a star's image moves during the exposure), rate_aid (the body rate
turned into detection kernels, and its check against the image), model (the streak's pixels),
fit_common (the fits' shared ground), free_fit (straight streaks, free; free_fit_kernel
compiled), path_fit (on the predicted path), groups (several stars on one path),
levenberg_marquardt (the batched solver), streak_spots (the stage's streak fits).
"""
