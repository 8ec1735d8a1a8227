"""Self-motion manifolds (SMMs) of arms with one degree of redundancy.

After Clark and Xie, "A learning-based method for computing self-motion
manifolds of redundant robots for real-time fault-tolerant motion planning"
(T-RO 2025): ground truth by nullspace projection, a Fourier representation,
cellular-automaton clustering, learned networks, and fault-tolerant planning.
"""
