from glob import glob

from setuptools import find_packages, setup

package_name = 'im_common'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/schema', glob('schema/*.json')),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/config/motors', glob('config/motors/*.yaml')),
        ('share/' + package_name + '/config/profiles', glob('config/profiles/*')),
        ('share/' + package_name + '/config/loads', glob('config/loads/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='IM drive stack maintainers',
    maintainer_email='drive-stack@example.org',
    description=('Shared motor model, parameters, frames, topics, message conversions '
                 'and the lock-step helper (ROS-free math plus thin ROS helpers).'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
        ],
    },
)
