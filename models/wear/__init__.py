"""The wear group: the wear map (backlash as a function of position and operating hours), its
fleet pooling, the wear clock that restarts at an adjustment, the basis it is built on, and one
axis's wear-rate map since its last change point as the fleet view shows it (``axis_map``)."""
