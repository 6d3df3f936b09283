"""Bundle adjustment against the BIM: problem arrays, options, problem files, the Ceres solve."""
