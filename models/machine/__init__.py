"""The machine beyond its linear axes: geometric models identified from measurements.

``kinematics``: the 12 geometric errors of a five-axis machine's two rotary axes and their play,
identified from probed calibration spheres (data contract section 13, seed 003);
``stiffness``: static stiffness from loaded circles; ``circle``: the diagnosis of a circular
test (ISO 230-4); ``volumetric``: the 21 geometric errors and the volumetric compensation;
``path_error``: the error along a programmed path.
"""
