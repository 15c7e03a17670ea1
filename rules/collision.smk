# Rules of the collision stage (not yet written).
