# Rules of the meshes stage (not yet written).
