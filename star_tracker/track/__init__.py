"""
Frame to frame: tracking around a predicted attitude (with a lost-in-space fallback and
delay compensation) and the body rate from successive attitudes or from one frame's streaks.
"""
