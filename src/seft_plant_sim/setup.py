from setuptools import find_packages, setup

package_name = 'seft_plant_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='seft developers',
    maintainer_email='dev@seft.invalid',
    description='Simulated actuator + specimen rig for substructure EFT',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'rig = seft_plant_sim.rig_node:main',
        ],
    },
)
