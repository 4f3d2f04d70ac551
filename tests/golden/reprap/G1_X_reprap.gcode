; backlash-pipeline compensation for RepRapFirmware M425 (RRF 3.5 or later)
; machine G1, axis X, from measured data
; scalar backlash = mean lost motion 4.348 um; the reversal varies by 0.998 um along the axis and the position error is not compensated
M425 X0.0043 ; backlash [mm]
