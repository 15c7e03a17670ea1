# Rules of the dr stage (not yet written).
