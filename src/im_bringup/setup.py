from glob import glob

from setuptools import find_packages, setup

package_name = 'im_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/schema', glob('schema/*.json')),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/config/runs', glob('config/runs/*.yaml')),
        ('share/' + package_name + '/config/sros2', glob('config/sros2/*.xml')),
        ('share/' + package_name + '/config/foxglove', glob('config/foxglove/*.json')),
        ('share/' + package_name + '/launch', glob('launch/*.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='IM drive stack maintainers',
    maintainer_email='drive-stack@example.org',
    description='Bringing the drive up: the launch file, configuration, the '
    'scenario runner, the graph and process starters, commissioning.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'scenario = im_bringup.entry:scenario',
            'commission = im_bringup.entry:commission',
            'live = im_bringup.entry:live',
        ],
    },
)
