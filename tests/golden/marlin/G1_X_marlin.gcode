; backlash-pipeline compensation for Marlin M425
; machine G1, axis X, from measured data
; scalar backlash = mean lost motion 4.348 um; the reversal varies by 0.998 um along the axis and the position error is not compensated
M425 X0.0043 ; backlash distance [mm]
M425 F1 ; apply it fully
