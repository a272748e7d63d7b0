//! Trajectory association, Umeyama alignment, ATE and RPE, plots
