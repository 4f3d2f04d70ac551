"""The wear group: the wear map (backlash as a function of position and operating hours), its
fleet pooling, the wear clock that restarts at an adjustment and the basis it is built on."""
