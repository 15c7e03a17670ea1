# Rules of the usd stage (not yet written).
