; backlash-pipeline compensation for RepRapFirmware M425
; machine G1, axis X, from measured data
; scalar backlash = mean lost motion 4.348 um; the reversal varies by 0.998 um along the axis and the position error is not compensated
; NOT CONFIRMED: M425 syntax of RepRapFirmware
M425 X0.0043 ; backlash [mm]
