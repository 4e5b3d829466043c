from setuptools import find_packages, setup

package_name = 'seft_msgs_py'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # the Fast DDS profile every seft process starts with (seft_msgs_py.dds)
    package_data={package_name: ['fastdds_profile.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='seft developers',
    maintainer_email='dev@seft.invalid',
    description='seft node-graph interface: topics, QoS, conversions, parameter schema',
    license='Apache-2.0',
)
