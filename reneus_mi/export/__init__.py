"""A specimen's package for a collection: the mesh, its metadata and its report page
(``python -m reneus_mi.export``)."""
