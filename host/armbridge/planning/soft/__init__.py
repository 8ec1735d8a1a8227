"""Planning for planar serial chains among polygons: the soft arm of the WJRRT paper (and OMPL's horn)."""
