"""The fold model: M5 geometry, mesh, linear elasticity (P2 FEM), loads and responses."""
