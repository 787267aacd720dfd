"""Training: skill metrics of recorded sessions (:mod:`.metrics`) and the session
report (:mod:`.report`)."""
