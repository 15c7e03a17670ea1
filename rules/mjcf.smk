# Rules of the mjcf stage (not yet written).
