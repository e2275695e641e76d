from glob import glob

from setuptools import find_packages, setup

package_name = 'im_observer'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='IM drive stack maintainers',
    maintainer_email='drive-stack@example.org',
    description='Full-order nonlinear observer of stator currents '
    'and rotor fluxes (seed 000 eq. 3.27 / 4.13).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'observer = im_observer.entry:observer'
        ],
    },
)
