"""The machine beyond its linear axes: geometric models identified from measurements.

``kinematics``: the 12 geometric errors of a five-axis machine's two rotary axes and their play,
identified from probed calibration spheres (data contract section 13, seed 003).
"""
