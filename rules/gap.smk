# Rules of the gap stage (not yet written).
