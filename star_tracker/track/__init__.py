# SPDX-License-Identifier: Apache-2.0
"""
Frame to frame: tracking around a predicted attitude, and the body rate.

Tracking has a lost-in-space fallback and delay compensation; the body rate comes from
successive attitudes or from one frame's streaks.
"""
