# Rules of the lab stage (not yet written).
