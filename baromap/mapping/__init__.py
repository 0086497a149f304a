"""Post-run mapping: floor-aware 2D graph SLAM, occupancy grids per floor, building model."""
