"""What the environments share: their argument checks (``checks``) and the optional extras (``extras``)."""
