"""What the environments share: their argument checks (:mod:`.checks`) and the optional extras (:mod:`.extras`)."""
