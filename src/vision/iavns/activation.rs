//! PI-inspired activation of the IA-VNS priors (paper section "IA-VNS PI activation").
