//! Stage 1 and the joint prior-based pose optimisation of the IA-VNS (paper sections
//! "IA-VNS rationale" and "IA-VNS prior").
