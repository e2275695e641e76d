from setuptools import find_packages, setup

package_name = 'im_recording'

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
    maintainer='IM drive stack maintainers',
    maintainer_email='drive-stack@example.org',
    description='Recording of a drive run: the MCAP writer and reader, the lossless '
    'recorder node, replay, recover, run analysis, report and plots.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'record = im_recording.entry:record',
            'replay = im_recording.entry:replay',
            'report = im_recording.entry:report',
            'recover = im_recording.entry:recover',
        ],
    },
)
