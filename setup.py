from setuptools import find_packages, setup

setup(
    name="lfd",
    version="0.1.0",
    description="Learning manipulation tasks from demonstrations with learned virtual landmarks "
                "(Bowen & Alterovitz), with a PyBullet executor",
    packages=find_packages(include=["lfd", "lfd.*", "sim", "sim.*"]),
    python_requires=">=3.10",
    # torch is pinned in the Makefile (installed first, CPU build); any recent torch works here.
    install_requires=[
        "torch>=2.1",
        "pytorch-kinematics>=0.7",
        "numpy>=1.24",
        "scipy>=1.10",
        "networkx>=3.0",
    ],
    extras_require={
        # The simulator, TensorBoard, plots and the test tools: what `make` installs.
        "sim": ["pybullet>=3.2.5", "example-robot-data>=4.0", "tensorboard>=2.12", "matplotlib>=3.6",
                "imageio>=2.30", "tqdm>=4.60"],
        "test": ["pytest>=7", "hypothesis>=6", "psutil>=5"],
    },
)
