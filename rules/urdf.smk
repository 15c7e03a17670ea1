# Rules of the urdf stage (not yet written).
