from glob import glob

from setuptools import find_packages, setup

package_name = 'im_adapt'

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
    description='Online adaptation of R_r and L_sr/L_r (seed 000 ch. 4).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'adapter = im_adapt.entry:adapter'
        ],
    },
)
