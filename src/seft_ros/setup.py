from setuptools import find_packages, setup

package_name = 'seft_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # the live view's page: every script and style shipped (no CDN)
    package_data={'seft_ros.live': ['static/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='seft developers',
    maintainer_email='dev@seft.invalid',
    description='Substructure effective force testing on ROS 2: numerics, nodes and CLI',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'seft = seft_ros.cli.main:main',
            'ground_motion_publisher = seft_ros.nodes.ground_motion_publisher:main',
            'reference_force_builder = seft_ros.nodes.reference_force_builder:main',
            'force_servo_controller = seft_ros.nodes.force_servo_controller:main',
            'recorder = seft_ros.nodes.recorder:main',
            'loop = seft_ros.nodes.loop:main',
            'link_emulator = seft_ros.cli.link_emulator:main',
        ],
        # computational models of other programs (seft_ros.core.models), by section key
        'seft_ros.computational_models': [
            'opensees = seft_ros.opensees.plugin:PLUGIN',
        ],
    },
)
